"""The digital twin: robot models (Pinocchio, example-robot-data) and inverse dynamics."""
