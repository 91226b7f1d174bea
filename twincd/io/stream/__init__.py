"""The block stream: a log of any form and length read at flat memory, in two layers.

- ``topics``: ``TopicReader``, the message layer: decoded batches of the wanted topics in about
  log-time order (``batch``: the batch types; ``backends``: one reader per storage form);
- ``samples``: ``iter_blocks`` / ``LogStream``, the sample layer: the joint-state samples
  ordered by stamp in ``SampleBlock``s, with labels and the twin's effort joined on (``head``:
  a log opened and read ahead; ``choice``: its topic and joints; ``counts``: what was dropped;
  ``parts``: the reorder buffer's parts).
"""

from twincd.io.stream.batch import Batch, BoolBatch, JointStateBatch, StringBatch
from twincd.io.stream.choice import OWN_PREFIX, choose_topic, warn_ignored_joints
from twincd.io.stream.counts import StreamCounts
from twincd.io.stream.samples import LogStream, SampleBlock, iter_blocks
from twincd.io.stream.topics import TopicReader

__all__ = [
    "OWN_PREFIX",
    "Batch",
    "BoolBatch",
    "JointStateBatch",
    "LogStream",
    "SampleBlock",
    "StreamCounts",
    "StringBatch",
    "TopicReader",
    "choose_topic",
    "iter_blocks",
    "warn_ignored_joints",
]
