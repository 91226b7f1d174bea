"""Running one per-log function over many logs, with the same results whatever runs them.

- ``run``: ``run_logs`` (keep-going, progress, failures as data: ``LogRun``, ``LogFailure``);
- ``local``: this process or local worker processes (``Executor``, ``Bound``, the workers'
  preloaded imports and their warnings carried back);
- ``cluster``: a ``dask.distributed`` scheduler or a LocalCluster (extra ``twincd[dask]``).

Import from the module that holds a name: this package exports nothing, so that importing it
loads neither a process pool nor Dask.
"""
