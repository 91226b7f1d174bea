"""The twincd command line: a thin typer layer over the ``twincd`` library (importing it changes
no process state: the program's signal handling is set up in ``main.main``)."""
