"""Scale-out on Dask: a field's tiles (and time chunks) as tasks, gathered into one Dataset.

Public API: :class:`FieldRun` (what to run), :func:`run_field` (run it on an embedded
LocalCluster, an existing scheduler or a given client), :func:`connect` (a client),
:func:`run_single` (the single-process reference), :class:`HaloField` (tiles with a geometry
halo). See ``docs/distributed.md``.
"""

from lightfit.distributed.run import (
    AGGREGATES,
    FieldRun,
    TaskSpec,
    connect,
    default_workers,
    gather,
    gpu_count,
    run_field,
    run_single,
    run_task,
    submit,
)
from lightfit.distributed.tiles import HaloField, check_tiles

__all__ = [
    "AGGREGATES",
    "FieldRun",
    "HaloField",
    "TaskSpec",
    "check_tiles",
    "connect",
    "default_workers",
    "gather",
    "gpu_count",
    "run_field",
    "run_single",
    "run_task",
    "submit",
]
