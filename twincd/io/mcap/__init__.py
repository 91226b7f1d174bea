"""MCAP, read in bulk and written in blocks.

- ``reader``: ``McapFile``, a file's channels, chunk list and a chunk's wanted messages;
  ``chunks``: a chunk's records decompressed and its messages gathered with numpy;
- ``writer``: ``AugmentedMcap`` (a log copied losslessly plus new channels), ``McapLogWriter``
  (a new log), ``write_augmented``; built on ``output`` (the file being written), ``channels``
  (schema and channel ids, QoS), ``messages`` (Message records in blocks), ``copy`` (the
  lossless copy) and ``convert`` (other log forms through rosbags);
- ``records``: the format's constants and the records packed by hand, shared by both sides.
"""

from twincd.io.mcap.channels import DEFAULT_QOS, QOS_KEY
from twincd.io.mcap.chunks import RawMessages, chunk_records, records_before_cut
from twincd.io.mcap.reader import ChunkRef, McapChannel, McapFile
from twincd.io.mcap.records import MAGIC, McapDamage
from twincd.io.mcap.writer import AugmentedMcap, McapLogWriter, NewTopic, write_augmented

__all__ = [
    "DEFAULT_QOS",
    "MAGIC",
    "QOS_KEY",
    "AugmentedMcap",
    "ChunkRef",
    "McapChannel",
    "McapDamage",
    "McapFile",
    "McapLogWriter",
    "NewTopic",
    "RawMessages",
    "chunk_records",
    "records_before_cut",
    "write_augmented",
]
