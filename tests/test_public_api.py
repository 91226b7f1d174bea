"""The public API as type checkers and importers see it: every name of ``twincd.__all__`` has
its real type (not ``Any``, which the lazy ``__getattr__`` alone would give), and importing
twincd or its CLI changes no process state (signal handlers, the environment)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import twincd

ROOT = Path(__file__).resolve().parent.parent


def _revealed(tmp_path: Path, names: list[str]) -> dict[str, str]:
    probe = tmp_path / "probe.py"
    probe.write_text("import twincd\n" + "".join(f"reveal_type(twincd.{n})\n" for n in names))
    done = subprocess.run(
        [sys.executable, "-m", "mypy", "--no-error-summary", str(probe)],
        cwd=ROOT,  # the project's mypy settings; twincd found in the source tree
        capture_output=True,
        text=True,
    )
    found = re.findall(r":(\d+): note: Revealed type is \"(.*)\"", done.stdout)
    assert len(found) == len(names), done.stdout + done.stderr
    return {names[int(line) - 2]: kind for line, kind in found}


def test_type_checkers_see_the_real_types(tmp_path: Path) -> None:
    pytest.importorskip("mypy")
    names = [n for n in twincd.__all__ if n != "__version__"]
    revealed = _revealed(tmp_path, names)
    assert [n for n, kind in revealed.items() if kind == "Any"] == []
    assert revealed["Calibration"].endswith(".Calibration")  # the class itself
    assert revealed["OnlineDetector"].endswith(".OnlineDetector")
    assert revealed["detect_file"].startswith("def (log: ")
    assert revealed["detect_file"].endswith(".DetectionSummary")


def test_every_exported_name_loads() -> None:
    for name in twincd.__all__:
        assert getattr(twincd, name) is not None


PROBE = """
import json, os, signal
before = signal.getsignal(signal.SIGTERM)
import twincd, twincd.twin, twincd.twin.dynamics, twincd.twin.robot, twincd_cli.main
print(json.dumps({"sigterm_unchanged": signal.getsignal(signal.SIGTERM) is before,
                  "omp": os.environ.get("OMP_WAIT_POLICY")}))
"""


def test_importing_changes_no_process_state() -> None:
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    done = subprocess.run(
        [sys.executable, "-c", PROBE], capture_output=True, text=True, env=env, check=True
    )
    assert json.loads(done.stdout) == {"sigterm_unchanged": True, "omp": None}


LOAD = """
import os
from twincd.twin.openmp import load_pinocchio
load_pinocchio()
print(os.environ.get("OMP_WAIT_POLICY"))
"""


@pytest.mark.parametrize(("given", "kept"), [(None, "PASSIVE"), ("ACTIVE", "ACTIVE")])
def test_pinocchio_loads_with_passive_openmp_waiting_unless_told(
    given: str | None, kept: str
) -> None:
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if given is not None:
        env["OMP_WAIT_POLICY"] = given
    done = subprocess.run(
        [sys.executable, "-c", LOAD], capture_output=True, text=True, env=env, check=True
    )
    assert done.stdout.strip() == kept
