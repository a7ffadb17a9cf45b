"""Design-space sweeps that fill the shared catalogue (docs/sweeps.md).

A sweep spec (TOML) names a geometry family, fixed parameters, design options and one
sampler — ``[grid]``, ``[[list]]`` or ``[lhs]`` — that expands into tasks. Running it:

1. ``spec``: parse and validate the spec (:func:`load_spec`, :func:`parse_spec`);
   ``samplers`` expands it into parameter sets, ``tasks`` into :class:`Task` s (:func:`expand`);
2. ``plan``: validate every task and compute its content key with the
   :class:`SegmentDesigner` — no meshing (:func:`plan_sweep`); invalid tasks become
   failures, tasks whose key the :class:`SweepStore` holds are skipped (resume), repeated
   keys run once;
3. ``run``: the rest go to an executor (``designer.executors``); in each worker
   ``worker.execute_task`` designs the segment and commits it to the store itself; the
   parent tracks outcomes, shows progress (tqdm, stderr), merges the committed entries in
   batches and appends failures to a JSON-lines log next to the catalogue (``report``)
   (:func:`run_sweep` returns a :class:`SweepReport`).

The plan and the run work on a :class:`Batch` of tasks: a sweep's (:func:`sweep_batch`) or a
scene's design segments (``designer.prepare``), through the same :func:`plan_batch` and
:func:`run_plan`.

The designer and the store are Protocols: real sweeps use :class:`FiniteElementDesigner`
and :class:`CatalogueStore` (HDF5); tests and benchmarks plug in cheap ones.
"""

from vertebra.designer.sweep.plan import SweepPlan, plan_batch, plan_sweep
from vertebra.designer.sweep.report import (FAILURE_LOG_SUFFIX, FAILURE_LOG_VERSION, SweepReport, TaskFailure,
                                            append_failures, failure_log_path)
from vertebra.designer.sweep.run import MERGE_EVERY, run_plan, run_sweep
from vertebra.designer.sweep.samplers import SAMPLERS, LatinHypercube, Sampler, latin_hypercube_unit
from vertebra.designer.sweep.spec import (DESIGN_OPTIONS, DesignOption, SweepSpec, design_options, keyed_options,
                                          load_spec, parse_spec)
from vertebra.designer.sweep.store import CatalogueStore, SweepStore
from vertebra.designer.sweep.tasks import (Batch, FiniteElementDesigner, SegmentDesigner, Task, expand, format_name,
                                           sweep_batch)
from vertebra.designer.sweep.worker import TaskOutcome, execute_task

__all__ = [
    "SweepSpec", "DesignOption", "DESIGN_OPTIONS", "design_options", "keyed_options", "load_spec", "parse_spec",
    "Sampler", "SAMPLERS", "LatinHypercube", "latin_hypercube_unit",
    "Task", "Batch", "expand", "sweep_batch", "format_name", "SegmentDesigner", "FiniteElementDesigner",
    "SweepStore", "CatalogueStore",
    "SweepPlan", "plan_batch", "plan_sweep",
    "TaskOutcome", "execute_task",
    "TaskFailure", "SweepReport", "failure_log_path", "append_failures", "FAILURE_LOG_SUFFIX", "FAILURE_LOG_VERSION",
    "MERGE_EVERY", "run_plan", "run_sweep",
]
