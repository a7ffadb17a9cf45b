"""Tasks (one segment to design each), batches of them, and the designer that plans and runs them.

A :class:`Batch` is what the plan/run machinery works on: the tasks and the file that asked for
them — a sweep spec (:func:`sweep_batch`) or a scene whose design segments are being prepared
(``designer.prepare``). A sweep asks a :class:`SegmentDesigner` four things: the families it knows, a task's
canonical parameters, its content key (both in the parent, before any meshing) and the
entry itself (in a worker). :class:`FiniteElementDesigner` is the real one (gmsh +
scikit-fem through ``designer.design_segment``); tests and benchmarks plug in cheap ones.
A designer instance travels to the worker processes, so it must pickle (a module-level
class with plain-data fields).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial
from typing import Callable, Collection, Protocol, runtime_checkable

from vertebra.designer.families import FAMILIES, canonical_parameters
from vertebra.designer.energy_sampling import entry_progress
from vertebra.designer.keys import entry_key
from vertebra.designer.segment import design_segment
from vertebra.designer.sweep.samplers import SAMPLERS
from vertebra.designer.sweep.spec import NameFormatter, SweepSpec, keyed_options
from vertebra.store.entry import SegmentEntry
from vertebra.core.errors import SpecError


@dataclass(frozen=True)
class Task:
    """One segment to design. ``parameters`` are canonical once planned; ``key`` is its content key.

    ``options`` are the spec's design options (``design_segment`` keyword arguments).
    """

    index: int
    family: str
    parameters: dict
    options: dict
    name: str | None = None
    key: str | None = None

    @property
    def key_options(self) -> dict:
        """The options that are part of the content key (``entry_key`` keyword arguments)."""
        return keyed_options(self.options)


def expand(spec: SweepSpec) -> list[Task]:
    """The spec's tasks in a deterministic order (raw parameters: fixed + sampled)."""
    sampled = SAMPLERS[spec.sampler].expand(spec.design)
    return [Task(index=i, family=spec.family, parameters={**spec.parameters, **values}, options=dict(spec.options))
            for i, values in enumerate(sampled)]


def format_name(spec: SweepSpec, task: Task) -> str | None:
    """The task's entry name from the spec's template (``{index}``, ``{family}``, any parameter)."""
    if spec.name is None:
        return None
    try:
        return NameFormatter().fill(spec.name, index=task.index, family=task.family, **task.parameters)
    except (KeyError, IndexError, ValueError, AttributeError, TypeError) as error:
        raise SpecError(f"template {spec.name!r} cannot be filled for task {task.index}: "
                        f"{type(error).__name__}: {error}", file=spec.source, field="name") from None


@dataclass(frozen=True)
class Batch:
    """Tasks to design into one catalogue, and the file that asked for them.

    ``origin`` names that file's kind in the failure log and the reports (``sweep``: a sweep
    spec; ``scene``: a scene being prepared); ``label`` titles the progress bar; ``names`` gives
    a task with canonical parameters its entry name (``None``: the designer's default name);
    ``describe`` opens the JSON report."""

    tasks: tuple
    source: str
    origin: str = "sweep"
    label: str = "sweep"
    names: Callable[[Task], str | None] | None = None
    describe: dict = field(default_factory=dict)


def sweep_batch(spec: SweepSpec) -> Batch:
    """The tasks of a sweep spec, named by its template."""
    return Batch(tuple(expand(spec)), spec.source, origin="sweep", label=f"sweep {spec.family}",
                 names=partial(format_name, spec),
                 describe={"spec": spec.source, "family": spec.family, "sampler": spec.sampler})


@runtime_checkable
class SegmentDesigner(Protocol):
    """What a sweep needs of a designer."""

    def families(self) -> Collection[str] | None:
        """The known family names; ``None``: accept any (the designer checks per task)."""
        ...

    def canonical(self, family: str, parameters: dict) -> dict:
        """Validated parameters with defaults filled; raises (GeometryError, ...) when invalid."""
        ...

    def key(self, task: Task) -> str:
        """The content key of the entry ``design(task)`` will return, without designing it."""
        ...

    def design(self, task: Task) -> SegmentEntry:
        """The catalogue entry of one task (runs in a worker process)."""
        ...


@dataclass(frozen=True)
class FiniteElementDesigner:
    """The real designer: ``designer.design_segment`` with the spec's design options."""

    def families(self) -> Collection[str]:
        return FAMILIES.keys()

    def canonical(self, family: str, parameters: dict) -> dict:
        return canonical_parameters(family, parameters)

    def key(self, task: Task) -> str:
        return entry_key(task.family, task.parameters, **task.key_options)

    def design(self, task: Task) -> SegmentEntry:
        progress = entry_progress(task.name or task.family, task.options.get("material", "linear"))
        return design_segment(task.family, dict(task.parameters), name=task.name, progress=progress, **task.options)
