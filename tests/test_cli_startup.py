"""Fast start: --version and --help load no heavy library (issue: `twincd --help` took 4–5 s)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

HEAVY = ("scipy", "sklearn", "torch", "pinocchio", "rosbags", "mcap", "matplotlib")

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
    "argv", [["--version"], ["--help"], ["detect", "--help"], ["fit", "--help"]]
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
