"""A synthetic xArm 7 plant that records logs with known collisions (``twincd synth``): a
stand-in for the seed paper's recordings, with everything the digital twin does not know.

``config`` (what a run set is drawn from) → ``plant`` (the "real" arm) → ``motion`` (its paths)
→ ``contact`` (hand presses) → ``simulate`` (one path, ``SynthRun``) → ``messages`` (its topics
as CDR) → ``write`` (MCAP and rosbag2 files, a whole run set).
"""
