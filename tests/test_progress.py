"""Progress on a terminal: over logs for several, within the log (its samples as they stream)
for one; never off a terminal."""

from __future__ import annotations

import io

from rich.console import Console
from support.clitools import run

from twincd.calibration import Calibration
from twincd.detection import detect_streamed
from twincd.pipeline import Setup
from twincd.progress import listening


def _terminal(monkeypatch) -> io.StringIO:
    from twincd_cli import common

    buffer = io.StringIO()
    monkeypatch.setattr(common, "stderr", Console(file=buffer, force_terminal=True, width=120))
    monkeypatch.setattr(common, "show_progress", lambda quiet: not quiet)
    return buffer


def test_the_library_tells_of_each_block(twin_calibration, twin_dataset):
    cal = Calibration.load(twin_calibration)
    told: list[int] = []
    with listening(told.append):
        summary = detect_streamed(
            twin_dataset / "test" / "test_0.mcap", cal, Setup.from_calibration(cal)
        )
    assert told and sum(told) == summary.samples
    detect_streamed(twin_dataset / "test" / "test_0.mcap", cal, Setup.from_calibration(cal))
    assert sum(told) == summary.samples  # no listener: nothing told


def test_one_log_shows_its_samples_on_a_terminal(twin_calibration, twin_dataset, monkeypatch):
    drawn = _terminal(monkeypatch)
    result = run("detect", twin_dataset / "test" / "test_0.mcap", "-c", twin_calibration)
    assert result.exit_code == 1, result.output
    text = drawn.getvalue()
    assert "detecting" in text and " samples" in text


def test_several_logs_show_a_bar_over_logs(twin_calibration, twin_dataset, monkeypatch):
    drawn = _terminal(monkeypatch)
    result = run("detect", twin_dataset / "test", "-c", twin_calibration, "-j", "1")
    assert result.exit_code == 1, result.output
    assert "0/2" in drawn.getvalue() or "1/2" in drawn.getvalue()


def test_nothing_is_drawn_quiet_or_off_a_terminal(twin_calibration, twin_dataset, monkeypatch):
    drawn = _terminal(monkeypatch)
    run("detect", twin_dataset / "test" / "test_0.mcap", "-c", twin_calibration, "-q")
    assert "samples" not in drawn.getvalue()
