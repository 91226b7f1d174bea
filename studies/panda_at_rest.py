"""What twincd makes of a real Franka Panda recording (franka_ros, ROS 1, nine joints on
``/joint_states``: the arm's seven then ``panda_finger_joint1/2``), through the CLI as a user
would run it: simulate, fit, detect.

The recording is not part of the repository; it is read from ``../shared/data/`` beside it when
present, and the script says so when absent.

    python studies/panda_at_rest.py
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

DATA = Path(__file__).parents[1] / ".." / "shared" / "data"
LOG = DATA / "real_panda_at_rest" / "joint_states.bag"


def twincd(*args: object) -> subprocess.CompletedProcess[str]:
    """Run the installed CLI; print its command line, exit code and stderr."""
    cmd = [sys.executable, "-m", "twincd_cli.main", *map(str, args)]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    print(f"$ twincd {' '.join(map(str, args))}  → exit {done.returncode}")
    for line in done.stderr.strip().splitlines():
        print(f"    {line}")
    return done


def main() -> int:
    if not LOG.exists():
        print(f"{LOG.resolve()} is absent: nothing to study")
        return 0
    from twincd.prepare.setup import read_log

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        twincd("simulate", LOG, "--robot", "panda", "-o", out / "panda.twin.mcap")
        twin = read_log(out / "panda.twin.mcap")
        arm = [n for n in twin.joint_names if "finger" not in n]
        sim = twin.select(arm).sim_effort
        assert sim is not None
        print(f"    joints read back from the twin log: {', '.join(twin.joint_names)}")
        print(f"    twin joints: {', '.join(arm)}; {len(twin)} samples over {twin.t_s[-1]:.2f} s")
        print(f"    twin effort mean per joint (N·m): {sim.mean(axis=0).round(2).tolist()}")
        fit = twincd("fit", LOG, "--robot", "panda", "-o", out / "cal.json")
        if fit.returncode == 0:
            cal = json.loads((out / "cal.json").read_text())
            print(f"    calibrated joints: {', '.join(cal['robot']['joint_names'])}")
            print(f"    fit: {json.dumps(cal['fit'].get('r2', cal['fit']))[:300]}")
            twincd("threshold", LOG, "-c", out / "cal.json")
            found = twincd("detect", LOG, "-c", out / "cal.json", "--json")
            if found.stdout:
                for log in json.loads(found.stdout)["logs"]:
                    print(
                        f"    detect: {log['samples']} samples, {log['collision_samples']} "
                        f"flagged, {len(log['events'])} event(s)"
                    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
