"""The read stage: logs in, MCAP out, by format and by job. Nothing here imports a later stage.

- ``logs``: which paths are logs (``expand_logs``), and ``JointStates`` (one log as arrays);
- ``options``: how to read a log (topics, joint map), recorded in the calibration;
- ``stream``: the block stream, ``TopicReader`` (decoded topic batches) under ``iter_blocks``
  (time-ordered joint-state samples with labels and the twin's effort);
- ``mcap``: MCAP read in bulk (``McapFile``) and written in blocks (``AugmentedMcap``,
  ``McapLogWriter``); ``sqlite3``: rosbag2's ``.db3`` storage read in bulk;
- ``sources``: rosbag2 metadata, non-logs refused, rosbags' reader for every other form;
- ``cdr``: ROS 2 CDR encoders and decoders; ``links``: the contact-link ground truth;
- ``atomic``: outputs that appear whole or not at all.

Import from the module or subpackage that holds a name; this package itself exports nothing,
so that importing one light module (``atomic``, ``options``) loads nothing heavy.
"""
