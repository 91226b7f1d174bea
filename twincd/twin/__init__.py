"""The digital twin: robot models (Pinocchio, example-robot-data) and inverse dynamics
(Pinocchio is loaded through ``twincd.twin.openmp.load_pinocchio``, for its OpenMP threads)."""
