"""``twincd watch``: a real Foxglove WebSocket server (foxglove_sdk) in the test process replays
tiny logs; watch must give the events of ``detect --causal`` on the same messages."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import build_twin_log
from support.clitools import assert_one_line_error, run
from support.needs import need
from support.replay import FakeClock, Replay, Scripted, read_messages

need("foxglove")
need("websockets")

SPEED = 16.0  # replay this much faster than recorded: 16 s of log in 1 s


def _fit_causal(dataset: Path, folder: Path) -> Path:
    """A causal calibration fitted on ``dataset``/train, its threshold set on ``dataset``/val."""
    path = folder / "causal.json"
    assert run("fit", dataset / "train", "-o", path, "--causal", "-q").exit_code == 0
    assert run("threshold", dataset / "val", "-c", path, "-q").exit_code == 0
    return path


@pytest.fixture(scope="module")
def causal_cal(twin_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _fit_causal(twin_dataset, tmp_path_factory.mktemp("watch_cal"))


def _lines(output: str) -> list[dict[str, object]]:
    return [json.loads(line) for line in output.splitlines() if line.startswith("{")]


def _watch_process(url: str, cal: Path, *args: str, **popen: Any) -> subprocess.Popen[Any]:
    """``twincd watch URL -c CAL ARGS`` running in a process of its own."""
    command = [sys.executable, "-m", "twincd_cli.main", "watch", url, "-c", str(cal), *args]
    return subprocess.Popen(command, **popen)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_watch_gives_the_events_of_detect_causal(twin_dataset, causal_cal, tmp_path):
    log = twin_dataset / "test" / "test_0.mcap"
    detected = run("detect", log, "-c", causal_cal, "--json", "-q")
    assert detected.exit_code == 1, detected.output
    expected = json.loads(detected.stdout)["logs"][0]
    with Replay(log, speed=SPEED) as replay:
        result = run("watch", replay.url, "-c", causal_cal, "--json", "--idle-timeout", "1")
    assert result.exit_code == 1, (result.stdout, result.stderr)
    lines = _lines(result.stdout)
    events = [{k: v for k, v in d.items() if k not in ("type", "segment")} for d in lines[:-1]]
    assert all(d["type"] == "event" for d in lines[:-1])
    assert events == expected["events"]
    summary = lines[-1]
    assert summary["type"] == "summary"
    assert summary["samples"] == expected["samples"]
    assert summary["events"] == len(expected["events"]) and summary["collision"] is True
    assert summary["ended"] == "idle" and summary["segments"] == 1


def test_the_library_iterates_events_status_and_a_summary(twin_dataset, causal_cal):
    import twincd
    from twincd.live import WatchEvent, WatchStatus, WatchSummary

    log = twin_dataset / "test" / "test_1.mcap"
    with Replay(log, speed=SPEED) as replay:
        items = list(twincd.watch(replay.url, causal_cal, idle_timeout_s=1.0, status_every_s=0.2))
    assert isinstance(items[-1], WatchSummary)
    assert any(isinstance(i, WatchStatus) for i in items)
    status = [i for i in items if isinstance(i, WatchStatus)]
    assert max(s.rate_hz for s in status) > 0 and status[-1].threshold > 0
    events = [i for i in items if isinstance(i, WatchEvent)]
    assert len(events) == items[-1].events > 0
    assert items[-1].latency_ms["p50"] >= 0


def test_a_source_that_never_comes_is_exit_2_after_the_timeout(causal_cal):
    url = f"ws://127.0.0.1:{_free_port()}"
    start = time.monotonic()
    result = run("watch", url, "-c", causal_cal, "--connect-timeout", "0.5")
    assert time.monotonic() - start < 5
    assert_one_line_error(result, "cannot reach")
    assert "0.5 s" in result.stderr


def test_a_server_without_joint_states_is_exit_2(causal_cal):
    with Replay(channels={"/chatter": ("std_msgs/msg/String", b"string data")}) as replay:
        result = run("watch", replay.url, "-c", causal_cal, "--connect-timeout", "0.5")
    assert_one_line_error(result, "/joint_states")
    assert "/chatter" in result.stderr


def test_a_channel_of_another_type_is_exit_2(causal_cal):
    spec = {"/joint_states": ("std_msgs/msg/String", b"string data")}
    with Replay(channels=spec) as replay:
        result = run("watch", replay.url, "-c", causal_cal, "--connect-timeout", "2")
    assert_one_line_error(result, "std_msgs/msg/String")


def test_a_zero_phase_calibration_is_refused(twin_calibration):
    result = run("watch", "ws://127.0.0.1:1", "-c", twin_calibration)
    assert_one_line_error(result, "zero-phase")
    assert "--causal" in result.stderr


def test_a_server_that_restarts_starts_a_new_segment(twin_dataset, causal_cal, tmp_path):
    log = twin_dataset / "test" / "test_0.mcap"
    channels, messages = read_messages(log)
    first = messages[: len(messages) // 3]
    # the restarted source's clock starts again, a minute earlier
    from twincd.io.cdr import decode_joint_states, joint_state_cdr

    again = []
    for topic, t, data in messages[: len(messages) // 3]:
        if topic in ("/joint_states", "/twincd/sim_effort"):
            g = decode_joint_states(np.frombuffer(data, np.uint8)[None, :])[0]
            stamp = g.stamp_ns - 60_000_000_000
            data = next(
                iter(joint_state_cdr(stamp, list(g.names), g.position, g.velocity, g.effort))
            )
        again.append((topic, t, bytes(data)))
    replay = Replay(channels=channels, messages=first, speed=SPEED)
    port = replay.port
    import threading

    from twincd.live import WatchNotice, WatchSummary, watch

    items: list[object] = []
    thread = threading.Thread(
        target=lambda: items.extend(
            watch(replay.url, causal_cal, idle_timeout_s=1.5, connect_timeout_s=5)
        )
    )
    thread.start()
    replay.done.wait(10)
    replay.stop()
    time.sleep(0.3)
    with Replay(channels=channels, messages=again, speed=SPEED, port=port) as second:
        second.done.wait(10)
        thread.join(15)
    summary = items[-1]
    assert isinstance(summary, WatchSummary)
    assert summary.segments == 2, summary
    assert summary.late == 0
    # the server going away and coming back is said, through the real transport
    notices = [i.kind for i in items if isinstance(i, WatchNotice)]
    assert notices == ["source gone", "source back"] and summary.reconnects == 1
    assert summary.samples > 0.9 * 2 * len([m for m in first if m[0] == "/joint_states"])


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_ends_the_session_with_its_summary(twin_dataset, causal_cal, signum):
    log = twin_dataset / "test" / "test_0.mcap"
    with Replay(log, speed=4.0, loop=True) as replay:
        env = {**os.environ, "NO_COLOR": "1"}
        proc = _watch_process(
            replay.url,
            causal_cal,
            "--json",
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        assert replay.listener.subscribed.wait(30), "the watch never subscribed"
        time.sleep(0.5)
        proc.send_signal(signum)
        out, err = proc.communicate(timeout=20)
    assert proc.returncode in (0, 1), err
    summary = _lines(out)[-1]
    assert summary["type"] == "summary" and summary["ended"] == "stopped"
    assert summary["samples"] > 0
    assert proc.returncode == (1 if summary["collision"] else 0)


# ---------------------------------------------------------------- -o SESSION.mcap


def _topics(path: Path) -> dict[str, int]:
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    counts = summary.statistics.channel_message_counts
    return {c.topic: counts.get(cid, 0) for cid, c in summary.channels.items()}


def test_the_session_file_holds_what_arrived_and_twincds_channels(
    twin_dataset, causal_cal, tmp_path
):
    log = twin_dataset / "test" / "test_0.mcap"
    session = tmp_path / "session.mcap"
    # at a quarter of the speed: a loaded machine that starves watch for a moment makes a sample
    # late (dropped live, kept in the session), and detect on the session then counts one more
    with Replay(log, speed=SPEED / 4) as replay:
        result = run(
            "watch",
            replay.url,
            "-c",
            causal_cal,
            "--json",
            "--idle-timeout",
            "1",
            "-o",
            session,
            "--label-topic",
            "/collision_flag",
        )
    assert result.exit_code == 1, result.stderr
    summary = _lines(result.stdout)[-1]
    topics = _topics(session)
    source_counts = _topics(log)
    for topic in ("/joint_states", "/twincd/sim_effort", "/collision_flag"):
        assert topics[topic] == source_counts[topic], topic  # the label topic too
    for topic in ("/twincd/residual", "/twincd/score", "/twincd/collision"):
        assert topics[topic] == summary["samples"]
    assert topics["/twincd/event"] == summary["events"]
    # the metadata says what was synthesised
    from mcap.reader import make_reader

    with open(session, "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    assert "publish_time" in meta["twincd.session"]["synthesised"]
    # detect --causal on the session finds the same events; evaluate can judge it
    again = run("detect", session, "-c", causal_cal, "--json", "-q")
    events = [
        {k: v for k, v in d.items() if k not in ("type", "segment")}
        for d in _lines(result.stdout)[:-1]
    ]
    assert json.loads(again.stdout)["logs"][0]["events"] == events
    judged = run(
        "evaluate", session, "-c", causal_cal, "--json", "-q", "--methods", "friction-whitened"
    )
    assert judged.exit_code == 0, judged.stderr
    assert json.loads(judged.stdout)["positives"] > 0
    # a second session may replace twincd's own session file; not another file
    other = tmp_path / "other.mcap"
    other.write_bytes(log.read_bytes())
    refused = run("watch", "ws://127.0.0.1:1", "-c", causal_cal, "-o", other)
    assert_one_line_error(refused, "overwrite")


@pytest.fixture(scope="module")
def xarm_causal(xarm_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A causal calibration whose twin runs on the robot model (the logs carry no twin)."""
    return _fit_causal(xarm_dataset, tmp_path_factory.mktemp("watch_xarm"))


def test_a_session_records_the_twin_effort_computed_live(xarm_dataset, xarm_causal, tmp_path):
    log = next((xarm_dataset / "test").glob("*.mcap"))
    assert "/twincd/sim_effort" not in _topics(log)
    expected = json.loads(run("detect", log, "-c", xarm_causal, "--json", "-q").stdout)["logs"][0]
    session = tmp_path / "session.mcap"
    with Replay(log, speed=SPEED) as replay:
        result = run(
            "watch", replay.url, "-c", xarm_causal, "--json", "--idle-timeout", "1", "-o", session
        )
    assert result.exit_code == (1 if expected["events"] else 0), result.stderr
    summary = _lines(result.stdout)[-1]
    assert summary["samples"] == expected["samples"]
    topics = _topics(session)
    for topic in ("/twincd/sim_effort", "/twincd/residual", "/twincd/score", "/twincd/collision"):
        assert topics[topic] == expected["samples"], topic
    # the session's τ̂ is what detect's twin computes: detect now takes it from the file
    # instead of simulating, and finds the same events to the last bit
    inspected = json.loads(run("inspect", session, "--json", "-q").stdout)
    assert "/twincd/sim_effort" in json.dumps(inspected)
    again = json.loads(run("detect", session, "-c", xarm_causal, "--json", "-q").stdout)["logs"][0]
    assert again["events"] == expected["events"]


def _partial_topics(path: Path) -> dict[str, int]:
    """Messages per topic of an MCAP file read as a stream up to its damage."""
    from mcap.stream_reader import StreamReader

    counts: dict[str, int] = {}
    channels: dict[int, str] = {}
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False).records:
                kind = type(record).__name__
                if kind == "Channel":
                    channels[record.id] = record.topic
                elif kind == "Message":
                    topic = channels[record.channel_id]
                    counts[topic] = counts.get(topic, 0) + 1
        except Exception:  # the cut: what came before it is what a reader gets
            pass
    return counts


@pytest.mark.parametrize("twin", ["from the source", "computed live"])
def test_a_killed_session_stays_readable(
    twin_dataset, causal_cal, xarm_dataset, xarm_causal, tmp_path, twin
):
    if twin == "from the source":
        log, cal = twin_dataset / "test" / "test_0.mcap", causal_cal
    else:
        log, cal = next((xarm_dataset / "test").glob("*.mcap")), xarm_causal
    session = tmp_path / "killed.mcap"
    with Replay(log, speed=4.0, loop=True) as replay:
        proc = _watch_process(replay.url, cal, "-o", str(session), "-q")
        assert replay.listener.subscribed.wait(30)
        time.sleep(2.0)
        proc.kill()
        proc.wait(10)
    result = run("detect", session, "-c", cal, "--json")
    assert result.exit_code in (0, 1), result.stderr
    assert "truncated" in result.stderr or "damage" in result.stderr, result.stderr
    assert json.loads(result.stdout)["logs"][0]["samples"] > 100
    topics = _partial_topics(session)
    for topic in ("/joint_states", "/twincd/sim_effort", "/twincd/residual", "/twincd/score"):
        assert topics.get(topic, 0) > 100, (topic, topics)


def _watch_until_lost(go_away: Any, source: str, cal: Path, timeout_s: str) -> dict[str, Any]:
    """``watch SOURCE`` while ``go_away`` runs on a thread (the source goes away for good): the
    summary is printed, then one error line and exit 2."""
    import threading

    thread = threading.Thread(target=go_away)
    thread.start()
    try:
        result = run("watch", source, "-c", cal, "--json", "--connect-timeout", timeout_s)
    finally:
        thread.join(30)
    assert_one_line_error(result, f"went away and did not come back within {timeout_s} s")
    summary = _lines(result.stdout)[-1]
    assert summary["type"] == "summary" and summary["ended"] == "source lost"
    return summary


def test_a_source_lost_mid_session_prints_the_summary_and_exits_2(twin_dataset, causal_cal):
    replay = Replay(twin_dataset / "test" / "test_0.mcap", speed=SPEED)

    def stop_when_done() -> None:
        replay.done.wait(30)
        replay.stop()  # the server goes away and does not come back

    try:
        summary = _watch_until_lost(stop_when_done, replay.url, causal_cal, "1")
    finally:
        replay.stop()
    assert summary["samples"] > 1000 and summary["collision"] is True  # what came is judged


def _swapped(messages: list[tuple[str, int, bytes]], late: set[int]) -> list:
    """Joint states sent out of order: each pair of neighbours swapped (10 ms apart, within
    the reorder window), and the ones numbered in ``late`` sent 200 samples later (2 s: far
    enough that a replay bunched by a loaded machine still delivers the newer samples first)."""
    states = [i for i, m in enumerate(messages) if m[0] == "/joint_states"]
    order = list(range(len(messages)))
    for a, b in zip(states[1::2], states[2::2], strict=False):
        order[a], order[b] = order[b], order[a]
    for k in sorted(late, reverse=True):
        i = order.index(states[k])
        order.insert(i + 2 * 200, order.pop(i))  # twin effort messages between: 2 per sample
    return [messages[i] for i in order]


def test_samples_out_of_order_are_sorted_within_the_window(twin_dataset, causal_cal):
    log = twin_dataset / "test" / "test_0.mcap"
    expected = json.loads(run("detect", log, "-c", causal_cal, "--json", "-q").stdout)["logs"][0]
    channels, messages = read_messages(log)
    with Replay(channels=channels, messages=_swapped(messages, set()), speed=SPEED) as replay:
        result = run("watch", replay.url, "-c", causal_cal, "--json", "--idle-timeout", "1")
    lines = _lines(result.stdout)
    assert lines[-1]["late"] == 0 and lines[-1]["samples"] == expected["samples"]
    events = [{k: v for k, v in d.items() if k not in ("type", "segment")} for d in lines[:-1]]
    assert events == expected["events"]
    # later than the window: dropped and counted, the rest judged (replayed at a quarter of the
    # speed: a loaded machine that starves watch for a moment must not hand it a late sample
    # together with the newer ones, which it would sort in)
    late = {300, 700, 1100}
    with Replay(channels=channels, messages=_swapped(messages, late), speed=SPEED / 4) as replay:
        result = run("watch", replay.url, "-c", causal_cal, "--json", "--idle-timeout", "1")
    summary = _lines(result.stdout)[-1]
    assert summary["late"] == len(late)
    assert summary["samples"] == expected["samples"] - len(late)


def _pty_text(fd: int) -> str:
    """All a pseudo-terminal shows until its other side closes."""
    chunks = []
    with contextlib.suppress(OSError):  # EIO once the other side is closed
        while data := os.read(fd, 4096):
            chunks.append(data)
    return b"".join(chunks).decode(errors="replace")


def test_a_terminal_shows_a_status_line(twin_dataset, causal_cal):
    import pty
    import threading

    log = twin_dataset / "test" / "test_0.mcap"
    threshold = json.loads(causal_cal.read_text())["threshold"]["value"]
    master, slave = pty.openpty()
    texts: list[str] = []
    reader = threading.Thread(target=lambda: texts.append(_pty_text(master)), daemon=True)
    reader.start()
    with Replay(log, speed=4.0) as replay:
        env = {k: v for k, v in os.environ.items() if k not in ("NO_COLOR", "TERM")}
        cmd = ["watch", replay.url, "-c", str(causal_cal), "--idle-timeout", "1", "--duration", "3"]
        proc = subprocess.run(
            [sys.executable, "-m", "twincd_cli.main", *cmd],
            stdout=subprocess.PIPE,
            stderr=slave,
            env={**env, "TERM": "xterm"},
            timeout=60,
            check=False,
        )
    os.close(slave)
    reader.join(5)
    os.close(master)
    shown = "".join(texts)
    status = [line for line in shown.split("\r") if " Hz, latency " in line]
    assert status, shown
    # rate, latency, score against the threshold, events, samples
    assert f"/ {threshold:.3g}," in status[-1] and "event(s)" in status[-1], status[-1]
    assert " Hz, latency " not in proc.stdout.decode()  # stdout keeps events and the summary
    assert proc.returncode in (0, 1)


def test_a_push_without_twin_effort_is_skipped(causal_cal, twin_dataset):
    """Samples whose twin effort did not come (NaN) are skipped, alone or a whole push of
    them, and the others score as if those had never been pushed."""
    from twincd import Calibration
    from twincd.detection import OnlineDetector
    from twincd.prepare.setup import read_log

    cal = Calibration.load(causal_cal)
    states = read_log(twin_dataset / "test" / "test_1.mcap")
    assert states.sim_effort is not None and states.effort is not None
    n = 600
    stamp, pos, vel = states.stamp_ns[:n], states.position[:n], states.velocity[:n]
    eff, sim = states.effort[:n], states.sim_effort[:n].copy()
    gone = np.zeros(n, bool)
    gone[200:240] = True  # a whole push without it
    gone[[5, 301, 302, 450]] = True  # single samples
    sim[gone] = np.nan
    whole = OnlineDetector(cal)
    ref = whole.push(stamp[~gone], pos[~gone], vel[~gone], eff[~gone], sim[~gone])
    det = OnlineDetector(cal)
    parts = [
        det.push(stamp[a:b], pos[a:b], vel[a:b], eff[a:b], sim[a:b])
        for a, b in ((0, 200), (200, 240), (240, 241), (241, 600))
    ]
    score = np.concatenate([p.score for p in parts])
    assert np.isnan(score[gone]).all() and det.skipped == int(gone.sum())
    np.testing.assert_array_equal(score[~gone], ref.score)


# ---------------------------------------------------------------- a scripted source, fake clock


@pytest.fixture
def clock(monkeypatch: pytest.MonkeyPatch) -> FakeClock:
    """watch's clock, moved only by the scripted source (no test depends on the machine's
    speed)."""
    import importlib

    module = importlib.import_module("twincd.live.watch")  # the module, not the function
    fake = FakeClock()
    monkeypatch.setattr(module, "time", fake)
    return fake


def _scripted(
    messages: list[tuple[str, int, bytes]], cal: Path, clock: FakeClock, **options: Any
) -> list[Any]:
    """Every item ``watch`` gives on ``messages`` from a scripted source (``drops`` and
    ``speed`` for the source, the rest for ``watch``)."""
    import twincd

    drops = options.pop("drops", ())
    source = Scripted(messages, clock, options.pop("speed", 1.0), drops)
    return list(twincd.watch(source, cal, idle_timeout_s=options.pop("idle", 3.0), **options))


def _events(items: list[Any]) -> list[dict[str, object]]:
    from twincd.live import WatchEvent

    return [i.event.to_dict() for i in items if isinstance(i, WatchEvent)]


def test_latency_is_counted_over_samples_not_the_idle_wait(twin_dataset, causal_cal, clock):
    """Before: the summary's latency maximum was the idle timeout (3052 ms): the last samples,
    held for newer ones that never came, were scored when the session ended. Now a sample
    leaves the reorder window at most the window after it arrived, and what the end of a
    session scores is not counted: every latency within the window and one poll."""
    import twincd

    log = twin_dataset / "test" / "test_0.mcap"
    expected = json.loads(run("detect", log, "-c", causal_cal, "--json", "-q").stdout)["logs"][0]
    items = _scripted(read_messages(log)[1], causal_cal, clock, idle=5.0)
    summary = items[-1]
    assert summary.ended == "idle" and summary.samples == expected["samples"]
    assert _events(items) == expected["events"]
    # the window, one poll, and what a segment's first samples wait for the derivative's
    # window (``start_hold_s``); not 5000
    start = twincd.OnlineDetector(twincd.Calibration.load(causal_cal)).start_hold_s * 1e3
    assert summary.latency_ms["max"] <= 20 + 50 + start


def test_a_source_that_goes_away_and_comes_back_is_said(twin_dataset, causal_cal, clock):
    """A notice when the source goes away and one when it is back (as ``--json`` lines of
    type "notice"), and the summary counts the reconnects; before, nothing was said."""
    from twincd.live import WatchNotice

    log = twin_dataset / "test" / "test_0.mcap"
    items = _scripted(read_messages(log)[1], causal_cal, clock, drops=((4.0, 6.5),))
    notices = [i for i in items if isinstance(i, WatchNotice)]
    assert [n.kind for n in notices] == ["source gone", "source back"]
    assert notices[0].warning and not notices[1].warning
    assert "went away (connection closed)" in notices[0].text
    assert notices[1].away_s == pytest.approx(2.5) and "back after 2.5 s" in notices[1].text
    assert notices[1].to_dict()["type"] == "notice"
    from twincd_cli.watch import _notice_line  # what the command writes on stderr

    assert _notice_line(notices[0]).startswith("twincd: warning: scripted: the source went")
    assert _notice_line(notices[1]) == "twincd: scripted: the source is back after 2.5 s"
    assert items[-1].reconnects == 1 and items[-1].samples > 0


def test_a_source_at_another_rate_than_the_calibration_is_said(causal_cal, tmp_path, clock):
    """As ``detect`` says it of a log: the source's rate, the calibration's, and that the
    filter follows the calibration; once."""
    from twincd.live import WatchNotice

    log = build_twin_log(tmp_path / "slow.mcap", rate_hz=50.0)
    detected = run("detect", log, "-c", causal_cal, "--json")
    items = _scripted(read_messages(log)[1], causal_cal, clock)
    notices = [i for i in items if isinstance(i, WatchNotice)]
    assert [n.kind for n in notices] == ["rate"]
    words = "is sampled every 20 ms, the calibration every 10 ms; its filter and gap rule"
    assert words in notices[0].text and words in detected.stderr


def test_a_source_sampled_over_the_gap_rule_below_the_calibration_is_refused(
    causal_cal, tmp_path, clock
):
    """Every 60 ms against the calibration's 10 ms every interval is a gap: refused in
    ``detect``'s words (a ``DataError``: exit 2) after its first ten intervals, before any of
    its samples is scored, so no event comes first (a push in its first second would give one
    on one-sample segments)."""
    import twincd
    from twincd.errors import DataError
    from twincd.live import WatchEvent

    log = build_twin_log(tmp_path / "slower.mcap", rate_hz=1000 / 60, bumps=((0.1, 0.5, 3.0),))
    detected = run("detect", log, "-c", causal_cal)
    source = Scripted(read_messages(log)[1], clock, 1.0, ())
    items = []
    with pytest.raises(DataError, match="intervals between its samples are gaps") as refused:
        for item in twincd.watch(source, causal_cal, idle_timeout_s=3.0):
            items.append(item)
    words = "10 of the 10 intervals between its samples are gaps, longer than 5 of the"
    assert words in str(refused.value) and detected.exit_code == 2
    assert "intervals between its samples are gaps" in detected.stderr
    assert not [i for i in items if isinstance(i, WatchEvent)]


def _renamed(messages: list[tuple[str, int, bytes]], prefix: str) -> list[tuple[str, int, bytes]]:
    """The joint states' joints named ``prefix`` + their name (one arm of two)."""
    from twincd.io.cdr import decode_joint_states, joint_state_cdr

    out = []
    for topic, t, data in messages:
        if topic == "/joint_states":
            g = decode_joint_states(np.frombuffer(data, np.uint8)[None, :])[0]
            names = [prefix + n for n in g.names]
            data = bytes(
                next(iter(joint_state_cdr(g.stamp_ns, names, g.position, g.velocity, g.effort)))
            )
        out.append((topic, t, data))
    return out


def test_watch_reads_one_arm_and_a_moved_urdf_as_every_command(
    xarm_dataset, xarm_causal, tmp_path, clock
):
    """``--joint-prefix`` / ``--joint-map`` and ``--robot`` on watch, as on every command:
    the same events as the arm's joints under their own names; a URDF of other dynamics is
    refused."""
    from support.robots import xarm_urdf

    from twincd.errors import CalibrationError

    log = next((xarm_dataset / "test").glob("*.mcap"))
    messages = read_messages(log)[1]
    plain = _events(_scripted(messages, xarm_causal, clock))
    prefixed = _renamed(messages, "left_")
    assert _events(_scripted(prefixed, xarm_causal, clock, joint_prefix="left_")) == plain
    by_map = {f"left_joint{i}": f"joint{i}" for i in range(1, 8)}
    moved = str(xarm_urdf(tmp_path / "moved" / "arm.urdf"))
    both = _scripted(prefixed, xarm_causal, clock, joint_map=by_map, robot=moved)
    assert _events(both) == plain
    heavier = str(xarm_urdf(tmp_path / "heavier.urdf", heavier=True))
    with pytest.raises(CalibrationError, match="other dynamics"):
        _scripted(messages, xarm_causal, clock, robot=heavier)
    refused = run("watch", "ws://127.0.0.1:1", "-c", xarm_causal, "--robot", heavier)
    assert_one_line_error(refused, "other dynamics")


def test_a_recorded_session_runs_the_twin_once_a_sample(
    xarm_dataset, xarm_causal, tmp_path, clock, monkeypatch
):
    """With ``-o`` at 100 Hz the detector's own τ̂ is recorded: the twin's inverse dynamics
    run once per sample, where they ran twice (668 against 433 µs a push)."""
    from twincd.twin import dynamics

    twinned: list[int] = []
    real = dynamics.inverse_dynamics

    def counting(robot: Any, q: Any, *args: Any, **kwargs: Any) -> Any:
        twinned.append(len(np.atleast_2d(q)))
        return real(robot, q, *args, **kwargs)

    monkeypatch.setattr(dynamics, "inverse_dynamics", counting)
    log = next((xarm_dataset / "test").glob("*.mcap"))
    session = tmp_path / "session.mcap"
    items = _scripted(read_messages(log)[1], xarm_causal, clock, record=session)
    assert sum(twinned) == items[-1].samples > 0
    recorded = _topics(session)
    assert recorded["/twincd/sim_effort"] == items[-1].samples
    # the contact links are recorded as the labels are, for evaluate to judge isolation later
    assert recorded["/collision_link"] == _topics(log)["/collision_link"] > 0


# ---------------------------------------------------------------- the ros2 source (rclpy)


def _ros_extra_installs_here() -> bool:
    """Where the extra twincd[ros] has wheels: Linux x86_64, CPython 3.10–3.13."""
    import platform

    return (
        sys.platform == "linux"
        and platform.machine() == "x86_64"
        and (3, 10) <= sys.version_info[:2] <= (3, 13)
    )


def _rclpy_or_skip() -> None:
    try:
        import rclpy  # noqa: F401
        import sensor_msgs.msg  # noqa: F401
    except ImportError:
        if os.environ.get("CI") == "true" and _ros_extra_installs_here():
            # CI installs twincd[ros]: on this platform its wheels exist
            pytest.fail("twincd[ros] should have installed rclpy on this platform")
        pytest.skip("rclpy is not installed (the extra twincd[ros], or a sourced ROS 2)")


def test_the_ros_extra_is_guarded_by_platform_markers():
    import tomllib

    root = Path(__file__).resolve().parent.parent
    extra = tomllib.loads((root / "pyproject.toml").read_text())["project"][
        "optional-dependencies"
    ]["ros"]
    assert all("platform_machine == 'x86_64'" in req and "Linux" in req for req in extra)


def test_ros2_gives_the_events_of_detect_causal(twin_dataset, causal_cal, monkeypatch):
    _rclpy_or_skip()
    # a domain of its own: another test run on this machine publishes on none of it
    monkeypatch.setenv("ROS_DOMAIN_ID", str(40 + os.getpid() % 50))
    import threading

    import rclpy
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState

    from twincd.live import WatchEvent, WatchSummary, watch

    log = twin_dataset / "test" / "test_0.mcap"
    expected = json.loads(run("detect", log, "-c", causal_cal, "--json", "-q").stdout)["logs"][0]
    _, messages = read_messages(log)
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("twincd_test_publisher", context=context)
    pubs = {
        t: node.create_publisher(JointState, t, 1000)
        for t in ("/joint_states", "/twincd/sim_effort")
    }
    items: list[object] = []
    thread = threading.Thread(
        target=lambda: items.extend(watch("ros2", causal_cal, idle_timeout_s=1.5))
    )
    thread.start()
    deadline = time.monotonic() + 30
    while any(p.get_subscription_count() == 0 for p in pubs.values()):  # discovery
        assert time.monotonic() < deadline, "watch never subscribed"
        time.sleep(0.05)
    time.sleep(0.2)
    for topic, _, data in messages:
        if topic in pubs:
            pubs[topic].publish(deserialize_message(data, JointState))
            time.sleep(0.0005)
    thread.join(30)
    node.destroy_node()
    rclpy.shutdown(context=context)
    summary = items[-1]
    assert isinstance(summary, WatchSummary)
    events = [i.event.to_dict() for i in items if isinstance(i, WatchEvent)]
    assert events == expected["events"]


def test_ros2_without_the_topic_is_exit_2_after_the_timeout(causal_cal, monkeypatch):
    _rclpy_or_skip()
    monkeypatch.setenv("ROS_DOMAIN_ID", "37")  # nobody publishes there
    start = time.monotonic()
    result = run("watch", "ros2", "-c", causal_cal, "--connect-timeout", "0.5")
    assert time.monotonic() - start < 20
    assert_one_line_error(result, "waited 0.5 s for topic(s) /joint_states")
    assert "on ROS 2 (domain 37)" in result.stderr and "ROS_DOMAIN_ID" in result.stderr


def test_ros2_without_rclpy_says_how_to_get_it(causal_cal, monkeypatch):
    monkeypatch.setitem(sys.modules, "rclpy", None)  # as where neither ROS 2 nor the extra is
    result = run("watch", "ros2", "-c", causal_cal, "--connect-timeout", "0.5")
    assert_one_line_error(result, "rclpy is not installed")
    assert "twincd[ros]" in result.stderr and "setup.bash" in result.stderr


def test_ros2_with_another_type_on_the_topic_is_exit_2(causal_cal, monkeypatch):
    _rclpy_or_skip()
    import rclpy
    from std_msgs.msg import String

    monkeypatch.setenv("ROS_DOMAIN_ID", str(40 + (os.getpid() + 1) % 50))
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("twincd_test_other_type", context=context)
    node.create_publisher(String, "/joint_states", 10)
    try:
        result = run("watch", "ros2", "-c", causal_cal, "--connect-timeout", "10")
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)
    assert_one_line_error(result, "topic /joint_states carries std_msgs/msg/String")


# ---------------------------------------------------------------- the zenoh source (rmw_zenoh)


def _zenoh_or_skip() -> Any:
    try:
        import zenoh
    except ImportError:
        if os.environ.get("CI") == "true":  # CI installs twincd[zenoh]: its wheels are abi3
            pytest.fail("twincd[zenoh] should have installed eclipse-zenoh")
        pytest.skip("eclipse-zenoh is not installed (the extra twincd[zenoh])")
    return zenoh


class _ZenohRobot:
    """A Zenoh peer listening on a free port that publishes as rmw_zenoh does."""

    def __init__(self, zenoh: Any) -> None:
        self.port = _free_port()
        config = zenoh.Config()
        config.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{self.port}"]))
        config.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(config)
        self.source = f"zenoh/tcp/127.0.0.1:{self.port}"

    def publisher(self, topic: str, dds_type: str) -> Any:
        key = f"0/{topic.strip('/')}/{dds_type}/RIHS01_{'0' * 64}"
        return self.session.declare_publisher(key)

    def wait_for_watch(self, publisher: Any) -> None:
        deadline = time.monotonic() + 30
        while not publisher.matching_status.matching:  # watch subscribed
            assert time.monotonic() < deadline, "watch never subscribed"
            time.sleep(0.05)

    def close(self) -> None:
        self.session.close()


def test_zenoh_gives_the_events_of_detect_causal(twin_dataset, causal_cal, monkeypatch):
    zenoh = _zenoh_or_skip()
    import threading

    from twincd.live import WatchEvent, WatchSummary, watch

    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    log = twin_dataset / "test" / "test_0.mcap"
    expected = json.loads(run("detect", log, "-c", causal_cal, "--json", "-q").stdout)["logs"][0]
    _, messages = read_messages(log)
    robot = _ZenohRobot(zenoh)
    joint_state = "sensor_msgs::msg::dds_::JointState_"
    pubs = {t: robot.publisher(t, joint_state) for t in ("/joint_states", "/twincd/sim_effort")}
    items: list[object] = []
    thread = threading.Thread(
        target=lambda: items.extend(watch(robot.source, causal_cal, idle_timeout_s=1.5))
    )
    thread.start()
    try:
        for pub in pubs.values():
            robot.wait_for_watch(pub)
        for topic, _, data in messages:
            if topic in pubs:
                pubs[topic].put(data)
                time.sleep(0.0003)
        thread.join(30)
    finally:
        robot.close()
    summary = items[-1]
    assert isinstance(summary, WatchSummary) and summary.samples == expected["samples"]
    events = [i.event.to_dict() for i in items if isinstance(i, WatchEvent)]
    assert events == expected["events"]


def test_zenoh_without_a_router_is_exit_2_after_the_timeout(causal_cal):
    _zenoh_or_skip()
    start = time.monotonic()
    result = run(
        "watch", f"zenoh/tcp/127.0.0.1:{_free_port()}", "-c", causal_cal, "--connect-timeout", "0.5"
    )
    assert time.monotonic() - start < 10
    assert_one_line_error(result, "cannot reach the Zenoh router within 0.5 s")


def test_zenoh_with_another_type_on_the_topic_is_exit_2(causal_cal):
    zenoh = _zenoh_or_skip()
    import threading

    robot = _ZenohRobot(zenoh)
    done = threading.Event()

    other = robot.publisher("/joint_states", "std_msgs::msg::dds_::String_")

    def publish() -> None:
        while not done.is_set():
            other.put(b"x")
            time.sleep(0.05)

    publisher = threading.Thread(target=publish, daemon=True)
    publisher.start()
    try:
        result = run("watch", robot.source, "-c", causal_cal, "--connect-timeout", "10")
    finally:
        done.set()
        publisher.join(35)
        robot.close()
    assert_one_line_error(result, "topic /joint_states carries std_msgs/msg/String")


def test_zenoh_router_lost_mid_session_prints_the_summary_and_exits_2(twin_dataset, causal_cal):
    zenoh = _zenoh_or_skip()

    _, messages = read_messages(twin_dataset / "test" / "test_0.mcap")
    robot = _ZenohRobot(zenoh)
    joint_state = "sensor_msgs::msg::dds_::JointState_"
    pubs = {t: robot.publisher(t, joint_state) for t in ("/joint_states", "/twincd/sim_effort")}

    def publish_then_go() -> None:
        for pub in pubs.values():
            robot.wait_for_watch(pub)
        for topic, _, data in messages[: len(messages) // 2]:
            if topic in pubs:
                pubs[topic].put(data)
                time.sleep(0.0003)
        robot.close()  # the router goes away and does not come back

    summary = _watch_until_lost(publish_then_go, robot.source, causal_cal, "2")
    assert summary["samples"] > 300
