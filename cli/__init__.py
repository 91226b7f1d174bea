"""The twincd command line: a thin typer layer over the ``twincd`` library."""
