"""``open_source``: the live source a SOURCE argument names, by its form (the transports are
listed in ``twincd.live.source``); each transport's module is imported only when it is named."""

from __future__ import annotations

from twincd.live.source import Source, SourceError


def open_source(spec: str, connect_timeout_s: float = 10.0) -> Source:
    """The source that ``spec`` names (see the module's docstring)."""
    text = spec.strip()
    if text.startswith(("ws://", "wss://")):
        from twincd.live.foxglove import FoxgloveSource

        return FoxgloveSource(text, connect_timeout_s)
    if text in ("ros2", "ros2:", "ros2://"):
        from twincd.live.ros2 import Ros2Source

        return Ros2Source(connect_timeout_s)
    if text == "zenoh" or text.startswith("zenoh/"):
        from twincd.live.zenoh import ZenohSource

        return ZenohSource(text.removeprefix("zenoh").lstrip("/"), connect_timeout_s)
    raise SourceError(
        f"unknown live source {spec!r}",
        "source",
        "give ws://HOST:PORT (a foxglove_bridge), ros2 or zenoh/tcp/HOST:PORT (rmw_zenoh)",
    )
