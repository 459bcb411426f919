"""Dataset-scale batch work on Dask (``faceanim batch``): a job file names one operation, its inputs
(paths, globs, lists, patterns on other inputs) and options; every combination of inputs is one
task. :mod:`.jobs` reads and expands the job file, :mod:`.manifest` records what is done (so a rerun
skips it and redoes what changed), :mod:`.runner` runs the tasks on a ``dask.distributed`` cluster
(a local one by default) with each face bound once and shared by its tasks.

The engine knows nothing of faceanim's commands: the command layer (:mod:`faceanim.cli.batch`)
hands it the operations, how to check a task, how to bind a face and how to run a task.
"""
