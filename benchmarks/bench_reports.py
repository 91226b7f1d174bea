"""Reports of a long log: ``detect`` alone against ``detect --report r.html --junit r.xml`` on
the same 20 min, 1 kHz xArm 7 log, side by side in one run.

    python benchmarks/bench_reports.py --cache /work/bench-cache

The logs come from ``bench_long.py`` (``--cache`` of that script: the 20 min log and the two
2 min logs). Calibration (not judged): ``twincd fit`` on the first 2 min log, ``twincd
threshold`` on the second, written to a temporary folder; the cached logs are only read.

Printed per command: wall seconds, CPU seconds, peak RSS (``os.wait4`` ru_maxrss, MB = 10⁶
bytes), and for the report run the extra seconds and the ratio to ``detect`` alone, and the
sizes of the HTML and JUnit files. Verdicts follow the reports issue: the report adds seconds,
not minutes (extra ≤ 10 s), the HTML stays under 5 MB, and peak memory stays flat (≤ 1.2× of
``detect`` alone + 30 MB for matplotlib). Exit 1 when a check fails. The machine is shared and
noisy: compare within one run.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

LONG = "xarm7_1khz_20min_seed3_v1.mcap"
FIT = "xarm7_1khz_2min_seed1_v1.mcap"
VAL = "xarm7_1khz_2min_seed2_v1.mcap"


def timed(argv: list[str], ok: tuple[int, ...] = (0,)) -> tuple[float, float, float]:
    """(wall s, cpu s, peak RSS MB) of one command."""
    start = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    code = os.waitstatus_to_exitcode(status)
    if code not in ok:
        err = proc.stderr.read().decode() if proc.stderr else ""
        sys.exit(f"{' '.join(argv)} exited {code}: {err}")
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss * 1024 / 1e6


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cache", type=Path, required=True, help="bench_long.py's --cache")
    parser.add_argument("--twincd", default=shutil.which("twincd") or "twincd")
    args = parser.parse_args()
    log = args.cache / LONG
    for name in (LONG, FIT, VAL):
        if not (args.cache / name).exists():
            sys.exit(f"{args.cache / name} is missing: build it with bench_long.py --cache")
    with tempfile.TemporaryDirectory(prefix="twincd-bench-reports-") as tmp:
        work = Path(tmp)
        cal = work / "cal.json"
        timed([args.twincd, "fit", str(args.cache / FIT), "-o", str(cal), "-q"])
        timed([args.twincd, "threshold", str(args.cache / VAL), "-c", str(cal), "-q"])
        detect = [args.twincd, "detect", str(log), "-c", str(cal), "-q", "--no-summary"]
        html, xml = work / "r.html", work / "r.xml"
        alone = timed(detect, (0, 1))
        with_report = timed([*detect, "--report", str(html), "--junit", str(xml)], (0, 1))
        md = work / "r.md"
        with_md = timed([*detect, "--report", str(md)], (0, 1))
        rows = [("detect", alone), ("detect --report r.md", with_md)]
        rows.append(("detect --report r.html --junit r.xml", with_report))
        print(f"{'command':40} {'s':>7} {'cpu s':>7} {'RSS MB':>7}")
        for name, (wall, cpu, rss) in rows:
            print(f"{name:40} {wall:7.1f} {cpu:7.1f} {rss:7.0f}")
        extra = with_report[0] - alone[0]
        size = html.stat().st_size / 1e6
        checks = {
            f"report adds {extra:.1f} s ({with_report[0] / alone[0]:.2f}× detect) ≤ 10 s": extra
            <= 10,
            f"HTML {size:.2f} MB < 5 MB (JUnit {xml.stat().st_size} bytes)": size < 5,
            f"peak RSS {with_report[2]:.0f} MB ≤ 1.2 × {alone[2]:.0f} + 30 MB": with_report[2]
            <= 1.2 * alone[2] + 30,
        }
        for text, passed in checks.items():
            print(f"{'PASS' if passed else 'FAIL'}  {text}")
        return 0 if all(checks.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
