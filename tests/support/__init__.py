"""Test helpers, one module per job: ``builders`` (tiny logs written with rosbags' own writer, in
every storage form), ``clitools`` (the CLI run in-process, one-line error checks), ``streaming``
(chunked = whole helpers), ``chromium`` (a headless browser for the report tests),
``dask_preload`` (preloaded into the cluster tests' workers to kill them on demand)."""
