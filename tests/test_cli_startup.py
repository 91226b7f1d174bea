"""Fast start: --version and --help load no heavy library (issue: `twincd --help` took 4–5 s)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

HEAVY = (
    "scipy",
    "sklearn",
    "torch",
    "pinocchio",
    "rosbags",
    "mcap",
    "matplotlib",
    # live sources: imported when `watch` opens one, never for --help
    "websockets",
    "rclpy",
    "zenoh",
    "foxglove",
)

PROBE = """
import json, sys
from twincd_cli.main import app
try:
    app(sys.argv[1:])
except SystemExit:
    pass
print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] in %r)))
"""


@pytest.mark.parametrize(
    "argv",
    [["--version"], ["--help"], ["detect", "--help"], ["fit", "--help"], ["watch", "--help"]],
)
def test_help_and_version_import_nothing_heavy(argv: list[str]) -> None:
    done = subprocess.run(
        [sys.executable, "-c", PROBE % (HEAVY,), *argv],
        capture_output=True,
        text=True,
        check=True,
    )
    loaded = json.loads(done.stdout.strip().splitlines()[-1])
    assert loaded == [], f"`twincd {' '.join(argv)}` imported {loaded}"


def test_library_import_is_light() -> None:
    probe = f"import sys, twincd; print([m for m in sys.modules if m.split('.')[0] in {HEAVY!r}])"
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
    assert done.stdout.strip() == "[]"


def test_detect_on_an_mcap_loads_only_what_it_uses() -> None:
    # scipy.signal (84 MB, 0.55 s) and rosbags' type stores (70 ms) are not needed to read
    # bare MCAP and filter: the numpy CDR path and twincd.signal.iir do that
    sample_logs = Path(__file__).resolve().parent.parent / "sample_logs"
    log = sample_logs / "test" / "test_000.mcap"
    cal = sample_logs / "calibration.json"
    probe = PROBE % (HEAVY,)
    done = subprocess.run(
        [sys.executable, "-c", probe, "detect", str(log), "-c", str(cal), "-q"],
        capture_output=True,
        text=True,
        check=True,
    )
    loaded = set(json.loads(done.stdout.strip().splitlines()[-1]))
    assert "pinocchio" in loaded  # it did run the twin
    assert not {m for m in loaded if m.startswith(("scipy.signal", "rosbags.typesys.stores"))}
