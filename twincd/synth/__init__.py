"""A synthetic xArm 7 plant that records logs with known collisions (``twincd synth``)."""
