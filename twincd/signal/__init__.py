"""Signal stages: derivatives on real time and low-pass filters, whole or streamed."""
