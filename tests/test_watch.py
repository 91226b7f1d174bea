"""``twincd watch``: a real Foxglove WebSocket server (foxglove_sdk) in the test process replays
tiny logs; watch must give the events of ``detect --causal`` on the same messages."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("foxglove")
pytest.importorskip("websockets")

from support.clitools import assert_one_line_error, run
from support.replay import Replay, read_messages

SPEED = 16.0  # replay this much faster than recorded: 16 s of log in 1 s


@pytest.fixture(scope="module")
def causal_cal(twin_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("watch_cal") / "causal.json"
    assert run("fit", twin_dataset / "train", "-o", path, "--causal", "-q").exit_code == 0
    assert run("threshold", twin_dataset / "val", "-c", path, "-q").exit_code == 0
    return path


def _lines(output: str) -> list[dict[str, object]]:
    return [json.loads(line) for line in output.splitlines() if line.startswith("{")]


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

    from twincd.live import WatchSummary, watch

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
    assert summary.samples > 0.9 * 2 * len([m for m in first if m[0] == "/joint_states"])


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_ends_the_session_with_its_summary(twin_dataset, causal_cal, signum):
    log = twin_dataset / "test" / "test_0.mcap"
    with Replay(log, speed=4.0, loop=True) as replay:
        env = {**os.environ, "NO_COLOR": "1"}
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "twincd_cli.main",
                "watch",
                replay.url,
                "-c",
                str(causal_cal),
                "--json",
            ],
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
    with Replay(log, speed=SPEED) as replay:
        result = run(
            "watch", replay.url, "-c", causal_cal, "--json", "--idle-timeout", "1", "-o", session
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


def test_a_killed_session_stays_readable(twin_dataset, causal_cal, tmp_path):
    log = twin_dataset / "test" / "test_0.mcap"
    session = tmp_path / "killed.mcap"
    with Replay(log, speed=4.0, loop=True) as replay:
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "twincd_cli.main",
                "watch",
                replay.url,
                "-c",
                str(causal_cal),
                "-o",
                str(session),
                "-q",
            ],
        )
        assert replay.listener.subscribed.wait(30)
        time.sleep(2.0)
        proc.kill()
        proc.wait(10)
    result = run("detect", session, "-c", causal_cal, "--json")
    assert result.exit_code in (0, 1), result.stderr
    assert "truncated" in result.stderr or "damage" in result.stderr, result.stderr
    assert json.loads(result.stdout)["logs"][0]["samples"] > 100


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


def test_ros2_gives_the_events_of_detect_causal(twin_dataset, causal_cal):
    _rclpy_or_skip()
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
    time.sleep(1.0)
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
