"""Prepare: a log on disk to the arrays every model scores (read → twin → filter).

- ``setup``: ``Setup`` (how logs are read: options, robot, filter, joints, period) opens a log as
  a ``PreparedStream`` of frames or reads it whole as a ``PreparedLog``; ``read_log``;
- ``stream``: ``PreparedStream``, one log read, twinned and filtered block by block;
  ``prepared``: ``PreparedLog``, one whole log prepared; ``notices``: what preparing a log says
  of it (warnings) and the logs it refuses; ``joints``: the order of a log's joints, and the
  joints a run's logs agree on;
- ``settings``: ``SetupOptions``, the settings a user asks for by name, resolved to a ``Setup``
  on their own or against a calibration's;
- ``chain``: the one chain of stages (twin, derivative, low-pass filter, the model's features);
  ``robots``: the robot models it twins with (reduced to a log's joints, checked against a
  calibration's dynamics, their limits' bound on absurd samples); ``grid``: the coarse grid the
  chain runs on for fast-sampled logs; ``frames``: the frames the stages pass along;
- ``simulate``: a log copied with the twin's effort as a new channel; ``inspect``: what a log
  holds and what the chain would make of it, without running the twin;
- ``progress``: the samples-done callback a long run reports to.

Import from the module that holds a name: this package exports nothing, so that importing one
light module (``frames``, ``progress``) loads nothing heavy.
"""
