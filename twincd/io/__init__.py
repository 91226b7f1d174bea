"""Read and write logs: finding logs, reading joint states, CDR, MCAP output, atomic files."""
