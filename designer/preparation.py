"""Model only what a scene requires: design a scene's missing entries, resolve its design segments.

A ``type = "design"`` segment names a geometry family, its parameters and the design options
(mesh size, element order, material). :func:`prepare` turns each one into a sweep task — the
family's parameters checked, the content key computed by the same designer and design options
as ``vertebra design`` and ``vertebra sweep`` (:data:`~vertebra.designer.sweep.DESIGN_OPTIONS`)
— plans them against the catalogue, designs only the entries it lacks through the sweep's run
loop (same executors, progress bar, shard commits and failure log), and returns the scene with
every design segment whose entry is in the catalogue resolved to it (``type = "entry"``,
``entry`` = the key; the design is kept on the segment). The runtime then reads only those
entries, as for any scene.

Two segments (or two scenes, or a sweep and a scene) that describe the same design share one
key, hence one entry; a second run designs nothing.
"""

from __future__ import annotations

import dataclasses
import os
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

from vertebra.designer.sweep.plan import plan_batch
from vertebra.designer.sweep.report import SweepReport
from vertebra.designer.sweep.run import run_plan
from vertebra.designer.sweep.spec import DESIGN_OPTIONS, design_options
from vertebra.designer.sweep.store import CatalogueStore, SweepStore
from vertebra.designer.sweep.tasks import Batch, FiniteElementDesigner, SegmentDesigner, Task
from vertebra.store.errors import SceneError

if TYPE_CHECKING:       # the designer reads scenes as data; it never imports the solver at run time
    from vertebra.solver.scene import Scene

#: the material of an entry designed without a ``material`` option (small-strain linear elasticity)
LINEAR = "linear"


@dataclass(frozen=True)
class PreparedSegment:
    """One design segment of the scene: its entry's key and what became of that entry.

    ``status``: ``reused`` (already in the catalogue), ``designed`` (designed by this run),
    ``planned`` (a dry run would design it), ``failed``, ``not run`` (interrupted)."""

    segment: int
    family: str
    parameters: dict                  # canonical (defaults filled)
    options: dict                     # the design options in the content key
    key: str
    status: str

    def to_json(self) -> dict:
        return {"segment": self.segment, "family": self.family, "parameters": self.parameters, **self.options,
                "key": self.key, "status": self.status}


@dataclass(frozen=True)
class PrepareReport:
    """What :func:`prepare` did: one row per design segment, and the run of the missing designs."""

    scene: str
    catalogue: str | None
    segments: tuple                   # PreparedSegment, in scene order
    run: SweepReport | None           # None: the scene has no design segment
    elapsed_s: float = 0.0

    def _keys(self, status: str) -> list[str]:
        return list(dict.fromkeys(s.key for s in self.segments if s.status == status))

    @property
    def reused(self) -> list[str]:
        """Keys of the entries that were already in the catalogue."""
        return self._keys("reused")

    @property
    def designed(self) -> list[str]:
        """Keys of the entries this run designed."""
        return self._keys("designed")

    @property
    def planned(self) -> list[str]:
        """Keys a dry run would design."""
        return self._keys("planned")

    @property
    def dry_run(self) -> bool:
        return self.run is not None and self.run.dry_run

    @property
    def exit_code(self) -> int:
        """0: every design segment has its entry (or, dry run, could be planned); 1: a design
        failed; 130: interrupted."""
        return 0 if self.run is None else self.run.exit_code

    def to_json(self) -> dict:
        from vertebra import __version__

        run = self.run
        failures = [] if run is None else [
            {"segment": f.index, "key": f.task.key, "stage": f.stage, "error_type": f.error_type,
             "message": f.message} for f in run.failures]
        return {"vertebra_version": __version__, "scene": self.scene, "catalogue": self.catalogue,
                "dry_run": self.dry_run, "reused": self.reused, "designed": self.designed, "planned": self.planned,
                "failed": self._keys("failed"), "segments": [s.to_json() for s in self.segments],
                "executor": None if run is None else run.executor, "failures": failures,
                "failure_log": None if run is None else run.failure_log, "interrupted": bool(run and run.interrupted),
                "timing": {"total_s": self.elapsed_s,
                           "entries_per_minute": None if run is None else run.entries_per_minute}}

    def summary(self, rows: bool = True) -> str:
        """A one-line count, then (``rows``) one line per design segment, then any failures."""
        if not self.segments:
            return f"prepare {self.scene}: no design segments, nothing to do"
        head = "dry run" if self.dry_run else "prepare"
        counts = (f"{len(self.planned)} to design" if self.dry_run else f"{len(self.designed)} designed")
        lines = [f"{head} {self.scene}: {len(self.segments)} design segments, "
                 f"{len(dict.fromkeys(s.key for s in self.segments))} entries: {len(self.reused)} reused, {counts}"
                 + (f", {len(self._keys('failed'))} failed" if self._keys("failed") else "")
                 + f" (catalogue {self.catalogue})"]
        for s in self.segments if rows else ():
            lines.append(f"  {f'segment[{s.segment}]':12s} {s.family:18s} {s.key}  {s.status}")
        if self.run is not None:
            for f in self.run.failures:
                lines.append(f"  segment[{f.index}] failed [{f.stage}] {f.error_type}: {f.message}")
            if self.run.failure_log:
                lines.append(f"  failures logged to {self.run.failure_log}")
            if self.run.interrupted:
                lines.append("  interrupted: run the same command again to resume")
        return "\n".join(lines)


@dataclass(frozen=True)
class Design:
    """One segment design to prepare: the index it is reported under, its family, parameters
    and the design options it sets (absent ones are left to the designer's defaults)."""

    index: int
    family: str
    parameters: dict
    options: dict


def scene_designs(scene: "Scene") -> list[Design]:
    """The design segments of a parsed scene, by segment index."""
    return [Design(i, scene.segments[i].design.family, scene.segments[i].design.parameter_dict(),
                   scene.segments[i].design.options()) for i in scene.design_segments]


def _design_task(design: Design, source: str, run_options: dict) -> Task:
    """A design as a sweep task: its design options checked against the sweep's table (an
    invalid one is a SceneError naming the segment's field)."""
    given = dict(design.options)
    known = {option.name for option in DESIGN_OPTIONS}
    if "material" not in known and given.get("material", LINEAR) == LINEAR:
        given.pop("material", None)           # the designer's only material needs no option
    elif "material" not in known:
        raise SceneError(f"material {given['material']!r} needs a nonlinear entry, which this vertebra's designer "
                         f"does not make (it designs {LINEAR!r} entries)", file=source,
                         field=f"segment[{design.index}].material")
    options = design_options({**run_options, **given},
                             lambda name, reason: SceneError(reason, file=source, field=f"segment[{design.index}].{name}"))
    return Task(index=design.index, family=design.family, parameters=design.parameters, options=options)


def _check_families(designs: list[Design], source: str, designer: SegmentDesigner) -> None:
    families = designer.families()
    if families is None:
        return
    for design in designs:
        if design.family not in families:
            raise SceneError(f"unknown family {design.family!r} (known: {', '.join(sorted(families))})", file=source,
                             field=f"segment[{design.index}].family")


def design_tasks(designs: list[Design], source: str, *, label: str = "prepare", linear_solver: str = "auto",
                 estimate_accuracy: bool = True, designer: SegmentDesigner = FiniteElementDesigner()) -> Batch:
    """Designs as a batch of sweep tasks (task index = segment index); ``linear_solver`` and
    ``estimate_accuracy`` are the design options outside the content key."""
    _check_families(designs, source, designer)
    run_options = {"linear_solver": linear_solver, "estimate_accuracy": estimate_accuracy}
    tasks = tuple(_design_task(design, source, run_options) for design in designs)
    return Batch(tasks, source, origin="scene", label=label, describe={"scene": source})


def _statuses(run: SweepReport) -> dict[int, str]:
    """Status of each planned task by index (a duplicate shares the status of its first task)."""
    status = {t.index: "reused" for t in run.skipped}
    status.update({o.index: "designed" for o in run.completed})
    status.update({f.index: "failed" for f in run.failures})
    status.update({t.index: "planned" if run.dry_run else "not run" for t in run.todo if t.index not in status})
    status.update({t.index: status[first] for t, first in run.duplicates})
    return status


def resolve(scene: Scene, keys: dict[int, str], catalogue) -> Scene:
    """The scene with the design segments ``keys`` (segment index → entry key) resolved to
    their entries in ``catalogue`` (the design stays on the segment)."""
    segments = tuple(dataclasses.replace(s, type="entry", entry=keys[i]) if i in keys else s
                     for i, s in enumerate(scene.segments))
    return dataclasses.replace(scene, segments=segments, catalogue=str(catalogue))


def prepare_designs(designs: list[Design], catalogue, *, source: str, label: str = "prepare",
                    executor: str = "local", workers: int | None = None, scheduler: str | None = None,
                    start_method: str = "spawn", linear_solver: str = "auto", estimate_accuracy: bool = True,
                    progress: bool = True, dry_run: bool = False,
                    designer: SegmentDesigner = FiniteElementDesigner(),
                    store: Callable[[str], SweepStore] = CatalogueStore) -> PrepareReport:
    """Design the entries of ``designs`` missing from ``catalogue`` (``source`` names the file
    that asked for them in errors and reports); see :func:`prepare`."""
    start = time.perf_counter()
    batch = design_tasks(designs, source, label=label, linear_solver=linear_solver,
                         estimate_accuracy=estimate_accuracy, designer=designer)
    plan = plan_batch(batch, catalogue, store=store, designer=designer)
    if plan.invalid:
        failure = plan.invalid[0]
        raise SceneError(failure.message, file=source, field=f"segment[{failure.index}].parameters")
    run = run_plan(plan, executor=executor, workers=workers, scheduler=scheduler, start_method=start_method,
                   progress=progress, dry_run=dry_run, started=start)
    status = _statuses(run)
    segments = tuple(PreparedSegment(t.index, t.family, t.parameters, t.key_options, t.key, status[t.index])
                     for t in plan.tasks)
    return PrepareReport(source, str(catalogue), segments, run, time.perf_counter() - start)


def prepare(scene: "Scene", catalogue=None, **options) -> tuple["Scene", PrepareReport]:
    """Design the entries a scene's design segments need and are missing from the catalogue.

    ``scene``: a parsed scene (:class:`~vertebra.solver.scene.Scene`: the caller loads it, so
    that the designer reads scenes as data and never imports the solver); ``catalogue``: the
    catalogue file (default: the scene's ``[catalogue] path``). Returns the scene with every
    design segment whose entry is in the catalogue resolved to it (with ``dry_run``: only
    those already there; nothing is designed or written), and the report. A design that fails
    is reported (``report.exit_code`` 1, the failure log next to the catalogue), its segment
    stays unresolved. Raises SceneError (before any design) for a missing catalogue, an
    unknown family, parameters the family refuses or bad design options; OptionError for bad
    executor settings; CatalogueError when the catalogue's directory does not exist.
    ``options`` are those of :func:`prepare_designs` (executor, workers, scheduler,
    start_method, linear_solver, estimate_accuracy, progress, dry_run, designer, store).
    """
    start = time.perf_counter()
    catalogue = catalogue if catalogue is not None else scene.catalogue
    if not scene.design_segments:
        resolved = scene if catalogue is None else dataclasses.replace(scene, catalogue=str(catalogue))
        return resolved, PrepareReport(scene.source, None if catalogue is None else str(catalogue), (), None,
                                       time.perf_counter() - start)
    if catalogue is None:
        raise SceneError("design segments need a catalogue to hold their entries: give [catalogue] path in the "
                         "scene (or --catalogue)", file=scene.source, field="catalogue.path")
    label = f"prepare {scene.name or os.path.basename(scene.source)}"
    report = prepare_designs(scene_designs(scene), catalogue, source=scene.source, label=label, **options)
    report = dataclasses.replace(report, elapsed_s=time.perf_counter() - start)
    keys = {s.segment: s.key for s in report.segments if s.status in ("reused", "designed")}
    return resolve(scene, keys, catalogue), report
