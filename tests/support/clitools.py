"""Running the CLI in tests: typer's CliRunner and the one-line error check (contract: Exit codes
and streams)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from twincd_cli.main import app
from typer.testing import CliRunner

runner = CliRunner()


def run(*args: Any) -> Any:
    return runner.invoke(app, [str(a) for a in args])


def assert_one_line_error(result: Any, match: str = "", code: int = 2) -> None:
    """Exit ``code``, one ``twincd: error: <what> (<where>) — <hint>`` line, no traceback."""
    assert result.exit_code == code, (result.stdout, result.stderr)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("twincd: error: "), result.stderr
    assert " — " in lines[0] and match in lines[0], lines[0]
    assert "Traceback" not in result.output


def evaluate_methods(dataset: Path, *args: Any) -> dict[str, dict[str, Any]]:
    """``twincd evaluate --json`` on ``dataset``'s test logs, the methods fitted on its train
    logs and thresholded on its val logs (``args``: more options): each method's row by name,
    once the exit code (0) is checked."""
    result = run(
        "evaluate",
        dataset / "test",
        "--train",
        dataset / "train",
        "--val",
        dataset / "val",
        "--json",
        *args,
    )
    assert result.exit_code == 0, result.output
    return {m["name"]: m for m in json.loads(result.stdout)["methods"]}
