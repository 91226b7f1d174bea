"""Schemas and channels of an MCAP file being written: their ids, and the QoS metadata every
channel carries (what rosbag2 needs to replay it).

Ids asked for (a copied file's own) are kept where free, so copied chunks can pass through
unchanged; identical definitions share one id; ids of dropped input channels are never reused.
"""

from __future__ import annotations

from collections.abc import Collection

from mcap.records import Channel, Schema

from twincd.errors import OutputError

__all__ = ["DEFAULT_QOS", "QOS_KEY", "ChannelTable"]

# What `ros2 bag record` offers for a default publisher (reliable, volatile, keep-last).
DEFAULT_QOS = (
    "- history: 3\n  depth: 0\n  reliability: 1\n  durability: 2\n"
    "  deadline:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  lifespan:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  liveliness: 1\n"
    "  liveliness_lease_duration:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  avoid_ros_namespace_conventions: false"
)
QOS_KEY = "offered_qos_profiles"


class ChannelTable:
    """The schemas and channels defined so far, by id; ``where`` names the file in errors."""

    def __init__(self, where: str) -> None:
        self._where = where
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self._schema_ids: dict[tuple[str, str, bytes], int] = {}
        self._channel_ids: dict[tuple[str, int, str, tuple[tuple[str, str], ...]], int] = {}
        self._reserved: set[int] = set()  # channel ids of dropped input channels: never reused

    def _free_id(self, wanted: int | None, used: Collection[int]) -> int:
        if wanted is not None and wanted != 0 and wanted not in used:
            return wanted
        new = max([0, *used]) + 1
        if new > 0xFFFF:
            raise OutputError("too many channels for one MCAP file", self._where, "split the log")
        return new

    def schema(self, name: str, encoding: str, data: bytes, wanted: int | None = None) -> int:
        """The id of this schema: an existing identical one's, else ``wanted`` if free."""
        key = (name, encoding, bytes(data))
        if key not in self._schema_ids:
            schema_id = self._free_id(wanted, self.schemas.keys())
            self.schemas[schema_id] = Schema(
                id=schema_id, data=key[2], encoding=encoding, name=name
            )
            self._schema_ids[key] = schema_id
        return self._schema_ids[key]

    def channel(
        self,
        topic: str,
        schema_id: int,
        encoding: str,
        metadata: dict[str, str],
        wanted: int | None = None,
    ) -> int:
        """The id of this channel (QoS metadata added when missing), as ``schema`` does."""
        meta = dict(metadata)
        meta.setdefault(QOS_KEY, DEFAULT_QOS)
        key = (topic, schema_id, encoding, tuple(meta.items()))
        if key not in self._channel_ids:
            channel_id = self._free_id(wanted, self.channels.keys() | self._reserved)
            self.channels[channel_id] = Channel(
                id=channel_id,
                topic=topic,
                message_encoding=encoding,
                metadata=meta,
                schema_id=schema_id,
            )
            self._channel_ids[key] = channel_id
        return self._channel_ids[key]

    def reserve(self, channel_id: int) -> None:
        """Keep ``channel_id`` (a dropped input channel's) from being given to another."""
        self._reserved.add(channel_id)
