"""``harness sweep``: one scenario over seeds and ``--set`` values, each run a ``harness run`` on Dask.

Layers, lowest first: ``results`` (rows from run directories, results.csv / Parquet, run statuses),
``spec`` (seeds and ``--set`` values into validated runs), ``task`` (the Dask task: one run as a stoppable
subprocess), ``runner`` (cluster, submission, progress, Ctrl-C, resume), ``plot`` (metrics against
parameters). Reference: ``docs/sweep.md``.
"""
