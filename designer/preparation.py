"""Model only what a scene requires: design a scene's missing entries, resolve its design segments.

A ``type = "design"`` segment names a geometry family, its parameters and the design options
(mesh size, element order, material, sampling settings). :func:`prepare` turns each one into a
sweep task — the family's parameters checked, the content key computed by the same designer and
design options as ``vertebra design`` and ``vertebra sweep``
(:data:`~vertebra.designer.sweep.DESIGN_OPTIONS`) — plans them against the catalogue, designs
only the entries it lacks through the sweep's run loop (same executors, progress bar, shard
commits and failure log), and returns the scene with every design segment whose entry is in the
catalogue resolved to it (``type = "entry"``, ``entry`` = the key; the design is kept on the
segment). The runtime then reads only those entries, as for any scene.

Design segments with a nonlinear material (``svk``, ``neo_hookean``) are prepared in two
stages, so that the range their energy is fitted on covers what the scene asks of them:

1. the *linear* entries — the scene's linear design segments and the linear counterpart of
   every nonlinear one (the same design with ``material = "linear"``) — are designed or reused;
2. the scene is solved with them at the corners of its actuation box under its loads and
   gravity (:func:`~vertebra.designer.scene_range.estimate_ranges`); the ranges of the segments
   that share a design are joined and turned into that design's sampling settings
   (:func:`~vertebra.designer.scene_range.choose_sampling`: raised to the estimate, rounded up
   onto a coarse grid, never below the defaults; settings the scene gives win), which are part
   of the nonlinear entry's key; then the nonlinear entries are planned and designed like any.

Two segments (or two scenes, or a sweep and a scene) that describe the same design share one
key, hence one entry; a second run designs nothing.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import sys
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from vertebra import __version__
from vertebra.designer.energy_fit import FIT_LIMIT, error_up_to
from vertebra.designer.energy_sampling import ENTRY_PROGRESS, SamplingSettings
from vertebra.designer.families import family_of
from vertebra.designer.scene_range import (RANGE_SETTINGS, SamplingChoice, choose_sampling, estimate_ranges, uncovered,
                                           union)
from vertebra.designer.sweep.plan import plan_batch
from vertebra.designer.sweep.report import SweepReport
from vertebra.designer.sweep.run import run_plan
from vertebra.designer.sweep.spec import DESIGN_OPTIONS, design_options
from vertebra.designer.sweep.store import CatalogueStore, SweepStore
from vertebra.designer.sweep.tasks import Batch, FiniteElementDesigner, SegmentDesigner, Task
from vertebra.core.errors import CatalogueError, ConvergenceError, OptionError, SceneError
from vertebra.store.catalogue import open_catalogue

if TYPE_CHECKING:       # the designer reads scenes as data; it never imports the solver at run time
    from vertebra.solver.scene import Scene

#: the material of an entry designed without a ``material`` option (small-strain linear elasticity)
LINEAR = "linear"


@dataclass(frozen=True)
class PreparedSegment:
    """One design segment of the scene: its entry's key and what became of that entry.

    ``status``: ``reused`` (already in the catalogue), ``designed`` (designed by this run),
    ``planned`` (a dry run would design it), ``failed``, ``not run`` (interrupted, or a nonlinear
    design whose range could not be estimated: ``key`` is then None). A nonlinear design carries
    its ``sampling`` (:class:`~vertebra.designer.scene_range.SamplingChoice`: the range it is
    sampled for and where each bound came from) and ``warnings`` where it cannot cover the scene."""

    segment: int
    family: str
    parameters: dict                  # canonical (defaults filled)
    options: dict                     # the design options in the content key
    key: str | None
    status: str
    sampling: Any = None              # SamplingChoice (nonlinear designs prepared for a scene)
    warnings: tuple = ()
    refusal: str | None = None        # status "refused": why the entry's fit cannot serve the scene

    def to_json(self) -> dict:
        out = {"segment": self.segment, "family": self.family, "parameters": self.parameters, **self.options,
               "key": self.key, "status": self.status}
        if self.sampling is not None:
            out["range"] = self.sampling.to_json()
        if self.warnings:
            out["warnings"] = list(self.warnings)
        if self.refusal is not None:
            out["refusal"] = self.refusal
        return out


def _unique_keys(rows, status: str) -> list[str]:
    return list(dict.fromkeys(s.key for s in rows if s.status == status and s.key is not None))


@dataclass(frozen=True)
class PrepareReport:
    """What :func:`prepare` did: one row per design segment, and the run of the missing designs.

    For a scene with nonlinear design segments: ``counterparts`` (one row per nonlinear segment:
    its linear counterpart), ``linear_run`` (the run of the linear stage), ``estimate`` (the
    :class:`~vertebra.designer.scene_range.RangeEstimate` the sampling settings came from, None
    when it failed) and ``warnings`` (about the estimate itself)."""

    scene: str
    catalogue: str | None
    segments: tuple                   # PreparedSegment, in scene order
    run: SweepReport | None           # None: the scene has no design segment
    elapsed_s: float = 0.0
    counterparts: tuple = ()          # PreparedSegment of the linear counterparts of nonlinear designs
    linear_run: SweepReport | None = None
    estimate: Any = None              # RangeEstimate
    warnings: tuple = ()

    def _keys(self, status: str) -> list[str]:
        return _unique_keys(self.segments, status)

    @property
    def reused(self) -> list[str]:
        """Keys of the entries that were already in the catalogue."""
        return self._keys("reused")

    @property
    def designed(self) -> list[str]:
        """Keys of the entries this run designed."""
        return self._keys("designed")

    @property
    def refused(self) -> list[str]:
        """Keys of the entries refused: their fit cannot serve the scene (:func:`fit_refusal`)."""
        return self._keys("refused")

    @property
    def planned(self) -> list[str]:
        """Keys a dry run would design."""
        return self._keys("planned")

    @property
    def runs(self) -> tuple:
        return tuple(r for r in (self.linear_run, self.run) if r is not None)

    @property
    def dry_run(self) -> bool:
        return any(r.dry_run for r in self.runs)

    @property
    def exit_code(self) -> int:
        """0: every design segment has its entry (or, dry run, could be planned); 1: a design
        failed or an entry was refused (its fit cannot serve the scene); 130: interrupted."""
        codes = [r.exit_code for r in self.runs] + [1 for s in self.segments if s.status == "refused"]
        return 130 if 130 in codes else max(codes, default=0)

    def to_json(self) -> dict:
        failures = [{"segment": f.index, "key": f.task.key, "stage": f.stage, "error_type": f.error_type,
                     "message": f.message} for r in self.runs for f in r.failures]
        run = self.run or self.linear_run
        out = {"vertebra_version": __version__, "scene": self.scene, "catalogue": self.catalogue,
               "dry_run": self.dry_run, "reused": self.reused, "designed": self.designed, "planned": self.planned,
               "failed": self._keys("failed"), "refused": self.refused, "segments": [s.to_json() for s in self.segments],
               "executor": None if run is None else run.executor, "failures": failures,
               "failure_log": next((r.failure_log for r in self.runs if r.failure_log), None),
               "interrupted": any(r.interrupted for r in self.runs),
               "timing": {"total_s": self.elapsed_s,
                          "entries_per_minute": None if self.run is None else self.run.entries_per_minute}}
        if self.counterparts:
            out["counterparts"] = {status: _unique_keys(self.counterparts, status)
                                   for status in ("reused", "designed", "planned", "failed")}
            out["range_estimate"] = None if self.estimate is None else {
                k: v for k, v in self.estimate.to_json().items() if k != "segments"}
            out["warnings"] = list(self.warnings)
        return out

    def _fit_summaries(self) -> dict:
        """Key → the fit's held-out load error against the linear entry's, for the nonlinear
        entries in the catalogue (designed or reused)."""
        keys = {s.key for s in self.segments
                if s.sampling is not None and s.key is not None and s.status in ("designed", "reused")}
        if not keys or self.dry_run:
            return {}
        out = {}
        try:
            with open_catalogue(self.catalogue) as catalogue:
                for key in keys:
                    fit = catalogue.load(key).energy
                    held = fit.fit_error.get("held_out", {}) if fit is not None and isinstance(fit.fit_error, dict) else {}
                    if "load_max" in held:
                        out[key] = (f"degree {fit.degree}, {fit.exponents.shape[0]} terms; held-out load error "
                                    f"{held['load_max']:.3g} of the load range (linear entry "
                                    f"{held.get('linear_load_max', float('nan')):.3g})")
        except CatalogueError:
            return {}
        return out

    def summary(self, rows: bool = True) -> str:
        """A one-line count, then (``rows``) one line per design segment (a nonlinear one with the
        range it is sampled for), then any failures and warnings."""
        if not self.segments:
            return f"prepare {self.scene}: no design segments, nothing to do"
        head = "dry run" if self.dry_run else "prepare"
        counts = (f"{len(self.planned)} to design" if self.dry_run else f"{len(self.designed)} designed")
        lines = [f"{head} {self.scene}: {len(self.segments)} design segments, "
                 f"{len(dict.fromkeys(s.key for s in self.segments))} entries: {len(self.reused)} reused, {counts}"
                 + (f", {len(self._keys('failed'))} failed" if self._keys("failed") else "")
                 + (f", {len(self._keys('refused'))} refused" if self._keys("refused") else "")
                 + f" (catalogue {self.catalogue})"]
        if self.counterparts:
            done = "to design" if self.dry_run else "designed"
            lines.append(f"  linear counterparts of the nonlinear designs (for the range estimate): "
                         f"{len(_unique_keys(self.counterparts, 'reused'))} reused, "
                         f"{len(_unique_keys(self.counterparts, 'planned' if self.dry_run else 'designed'))} {done}"
                         + (" (designed in memory for the estimate, not stored)" if self.dry_run else ""))
            if self.estimate is not None:
                lines.append(f"  range estimate: {len(self.estimate.actuations)} actuations solved with linear "
                             f"entries in {self.estimate.seconds:.2g} s"
                             + (f", {len(self.estimate.failed)} without equilibrium" if self.estimate.failed else ""))
        fits = self._fit_summaries() if rows else {}
        for s in self.segments if rows else ():
            lines.append(f"  {f'segment[{s.segment}]':12s} {s.family:18s} {s.key or '(key pending)'}  {s.status}")
            if s.sampling is not None:
                lines.append(f"    sampled for: {s.sampling.describe()}")
            if s.key in fits:
                lines.append(f"    fit: {fits[s.key]}")
        for s in self.segments:
            lines.extend(f"  warning: segment[{s.segment}]: {w}" for w in s.warnings)
        lines.extend(f"  segment[{s.segment}] refused: {s.refusal}" for s in self.segments if s.refusal)
        lines.extend(f"  warning: {w}" for w in self.warnings)
        for run in self.runs:
            for f in run.failures:
                lines.append(f"  segment[{f.index}] failed [{f.stage}] {f.error_type}: {f.message}")
            if run.failure_log:
                lines.append(f"  failures logged to {run.failure_log}")
            if run.interrupted:
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


@contextlib.contextmanager
def _entry_progress(on: bool):
    """While designing: with ``on``, the workers (which inherit the environment) report the
    stages inside a nonlinear entry on stderr (``energy_sampling.entry_progress``)."""
    saved = os.environ.get(ENTRY_PROGRESS)
    if on:
        os.environ[ENTRY_PROGRESS] = "1"
    else:
        os.environ.pop(ENTRY_PROGRESS, None)
    try:
        yield
    finally:
        if saved is None:
            os.environ.pop(ENTRY_PROGRESS, None)
        else:
            os.environ[ENTRY_PROGRESS] = saved


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
    with _entry_progress(progress and not dry_run):
        run = run_plan(plan, executor=executor, workers=workers, scheduler=scheduler, start_method=start_method,
                       progress=progress, dry_run=dry_run, started=start)
    status = _statuses(run)
    segments = tuple(PreparedSegment(t.index, t.family, t.parameters, t.key_options, t.key, status[t.index])
                     for t in plan.tasks)
    return PrepareReport(source, str(catalogue), segments, run, time.perf_counter() - start)


def prepare(scene: "Scene", catalogue=None, *, build_model: Callable | None = None,
            max_fit_error: float = FIT_LIMIT, **options) -> tuple["Scene", PrepareReport]:
    """Design the entries a scene's design segments need and are missing from the catalogue.

    ``scene``: a parsed scene (:class:`~vertebra.solver.scene.Scene`: the caller loads it, so
    that the designer reads scenes as data and never imports the solver); ``catalogue``: the
    catalogue file (default: the scene's ``[catalogue] path``); ``build_model``: the runtime's
    ``build_model(scene, entries)`` (:func:`vertebra.solver.build_model`), needed to estimate the
    ranges of nonlinear design segments (module docstring) — the caller passes it for the same
    reason. Returns the scene with every design segment whose entry is in the catalogue resolved
    to it (with ``dry_run``: only those already there; nothing is designed or written, except
    that the linear entries a range estimate needs and the catalogue lacks are designed in
    memory), and the report. A design that fails is reported (``report.exit_code`` 1, the
    failure log next to the catalogue), its segment stays unresolved. Raises SceneError (before
    any design) for a missing catalogue, an unknown family, parameters the family refuses or bad
    design options; OptionError for bad executor settings or a nonlinear design segment without
    ``build_model``; CatalogueError when the catalogue's directory does not exist.
    ``max_fit_error``: a nonlinear entry (designed or reused) whose energy fit misses its held-out
    samples by more than this fraction of its load range over the part of its box the scene
    needs is refused (:func:`fit_refusal`: status ``refused``, the segment stays unresolved,
    ``report.exit_code`` 1); ``math.inf`` accepts any fit.
    ``options`` are those of :func:`prepare_designs` (executor, workers, scheduler,
    start_method, linear_solver, estimate_accuracy, progress, dry_run, designer, store).
    """
    if not (isinstance(max_fit_error, (int, float)) and not isinstance(max_fit_error, bool)
            and max_fit_error > 0):
        raise OptionError(f"expected a positive number (inf: accept any fit), got {max_fit_error!r}",
                          field="max_fit_error")
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
    designs = scene_designs(scene)
    if all(_material(d) == LINEAR for d in designs):
        report = prepare_designs(designs, catalogue, source=scene.source, label=label, **options)
    else:
        if build_model is None:
            raise OptionError("nonlinear design segments need build_model (vertebra.solver.build_model) to estimate "
                              "the range their entries must cover", field="build_model")
        report = _prepare_nonlinear(scene, designs, catalogue, label, build_model, options, max_fit_error)
    report = dataclasses.replace(report, elapsed_s=time.perf_counter() - start)
    keys = {s.segment: s.key for s in report.segments if s.status in ("reused", "designed")}
    return resolve(scene, keys, catalogue), report


def resolve_prepared(scene: "Scene", catalogue=None, *, build_model: Callable | None = None,
                     max_fit_error: float = FIT_LIMIT) -> "Scene":
    """The scene with each design segment whose entry ``catalogue`` (default: the scene's)
    already holds resolved to it — what :func:`prepare` returns after designing, without
    designing anything: the content keys come from the same plan (a dry run). A nonlinear
    design segment is keyed by the range its linear counterparts' model spans, so it resolves
    only when every linear counterpart is in the catalogue too and ``build_model`` is given;
    segments whose entry is missing stay unresolved (``Scene.check_resolved`` names them). An
    entry :func:`prepare` refuses (``max_fit_error``) is a SceneError naming the segment and why."""
    catalogue = catalogue if catalogue is not None else scene.catalogue
    if not scene.design_segments or catalogue is None or not os.path.isfile(str(catalogue)):
        return scene if catalogue is None else dataclasses.replace(scene, catalogue=str(catalogue))
    designs = scene_designs(scene)
    quiet = {"progress": False, "dry_run": True, "executor": "serial"}
    if any(_material(d) != LINEAR for d in designs):
        counterparts = prepare_designs([linear_counterpart(d) for d in designs], catalogue, source=scene.source,
                                       **quiet)
        if build_model is None or any(row.status != "reused" for row in counterparts.segments):
            designs = [d for d in designs if _material(d) == LINEAR]
            scene_keys = {row.segment: row.key for row in counterparts.segments
                          if row.status == "reused" and row.segment in {d.index for d in designs}}
            return resolve(scene, scene_keys, catalogue)
    resolved, report = prepare(scene, catalogue, build_model=build_model, max_fit_error=max_fit_error, **quiet)
    refused = [s for s in report.segments if s.status == "refused"]
    if refused:
        raise SceneError(f"refused: {refused[0].refusal}", file=scene.source, field=f"segment[{refused[0].segment}]")
    return resolved


def _material(design: Design) -> str:
    return design.options.get("material", LINEAR)


def linear_counterpart(design: Design) -> Design:
    """The same design with the linear material (no sampling settings): what the range of a
    nonlinear design is estimated with."""
    options = {k: v for k, v in design.options.items() if k not in ("material", "sampling")}
    return Design(design.index, design.family, design.parameters, options)


def _say(progress: bool, message: str) -> None:
    if progress:
        print(message, file=sys.stderr, flush=True)


def _estimate_progress(progress: bool, every_s: float = 2.0):
    """A progress callback for the range estimate's forward solves: a line every ``every_s``
    seconds (none for a quick estimate)."""
    last = [0.0]

    def report(done: int, total: int, seconds: float) -> None:
        if progress and done < total and seconds - last[0] >= every_s:
            last[0] = seconds
            _say(progress, f"range estimate: {done}/{total} actuations solved with linear entries, "
                           f"{seconds:.1f} s")
    return report


def _prepare_nonlinear(scene, designs: list[Design], catalogue, label: str, build_model,
                       options: dict, max_fit_error: float = FIT_LIMIT) -> PrepareReport:
    """The two stages of a scene with nonlinear design segments (module docstring)."""
    progress, dry_run = options.get("progress", True), options.get("dry_run", False)
    designer = options.get("designer", FiniteElementDesigner())
    nonlinear = {d.index for d in designs if _material(d) != LINEAR}
    design_tasks(designs, scene.source, designer=designer)        # every design option checked before any design
    linear = prepare_designs([linear_counterpart(d) if d.index in nonlinear else d for d in designs], catalogue,
                             source=scene.source, label=f"{label}: linear entries", **options)
    rows = {row.segment: row for row in linear.segments}
    counterparts = tuple(rows[i] for i in sorted(nonlinear))
    pending = [PreparedSegment(d.index, d.family, rows[d.index].parameters, {}, None, "not run")
               for d in designs if d.index in nonlinear]
    base = dict(scene=scene.source, catalogue=str(catalogue), run=None, counterparts=counterparts,
                linear_run=linear.run)
    if any(row.status not in ("reused", "designed", "planned") for row in linear.segments):
        missing = "failed" if linear.exit_code == 1 else "was not run"
        return PrepareReport(segments=_in_order(linear.segments, nonlinear, pending), **base, warnings=(
            f"the nonlinear designs were not prepared: a linear entry their range estimate needs {missing}",))
    entries = _designed_in_memory(linear.segments, designer, options) if dry_run else {}
    warnings, estimate = [], None
    try:
        model = build_model(resolve(scene, {r.segment: r.key for r in linear.segments}, catalogue), entries)
        estimate = estimate_ranges(model, progress=_estimate_progress(progress))
    except ConvergenceError as error:
        warnings.append(f"no range estimate ({error}): the nonlinear entries are sampled over the default range")
    choices = _sampling_choices([d for d in designs if d.index in nonlinear], rows, estimate, catalogue, entries)
    chosen = [dataclasses.replace(d, options={**d.options, "sampling": choices[d.index].settings})
              for d in designs if d.index in nonlinear]
    report = prepare_designs(chosen, catalogue, source=scene.source, label=f"{label}: nonlinear entries", **options)
    fitted = _coverage(report.segments, estimate, catalogue)
    refused = _fit_checks(report.segments, estimate, catalogue, max_fit_error)
    rows_nl = tuple(dataclasses.replace(row, sampling=choices[row.segment],
                                        warnings=choices[row.segment].warnings + fitted.get(row.segment, ()),
                                        **({"status": "refused", "refusal": refused[row.segment]}
                                           if row.segment in refused else {}))
                    for row in report.segments)
    return PrepareReport(segments=_in_order(linear.segments, nonlinear, rows_nl), estimate=estimate,
                         warnings=tuple(warnings), **{**base, "run": report.run})


def _sampling_choices(designs: list[Design], rows: dict, estimate, catalogue, entries: dict) -> dict:
    """Per nonlinear design segment, its SamplingChoice: one per design (segments that share a
    linear counterpart, material and scene settings share the entry), from the union of their
    estimated ranges, or the defaults and scene settings when there is no estimate."""
    groups: dict = {}
    for d in designs:
        user = repr(sorted(d.options.get("sampling", {}).items()))
        groups.setdefault((rows[d.index].key, _material(d), user), []).append(d)
    choices = {}
    with _entries(catalogue, entries) as load:
        for (key, _, _), members in groups.items():
            entry, first = load(key), members[0]
            radius = family_of(first.family).outer_radius(rows[first.index].parameters)
            user = first.options.get("sampling")
            if estimate is None:
                choice = _default_choice(user, entry.n_cavities, _material(first),
                                         np.linalg.norm(entry.rest_translation) / radius)
            else:
                choice = choose_sampling(union(estimate.segments[d.index] for d in members),
                                         compliance=entry.compliance, rest_translation=entry.rest_translation,
                                         radius=radius, material=_material(first), user=user)
            choices.update({d.index: choice for d in members})
    return choices


def _in_order(linear_rows, nonlinear: set, nonlinear_rows) -> tuple:
    rows = [r for r in linear_rows if r.segment not in nonlinear] + list(nonlinear_rows)
    return tuple(sorted(rows, key=lambda r: r.segment))


def _default_choice(user: dict | None, cavities: int, material: str, slenderness: float):
    """The choice when no range could be estimated: the scene's settings, the defaults otherwise."""
    settings = SamplingSettings.from_dict(user).resolved(cavities, material)
    user = dict(user or {})
    return SamplingChoice(user, {n: getattr(settings, n) for n in RANGE_SETTINGS},
                          {n: "scene setting" if n in user else "default" for n in RANGE_SETTINGS},
                          {n: None for n in RANGE_SETTINGS}, cavities=cavities,
                          slenderness=slenderness)


def _designed_in_memory(rows, designer: SegmentDesigner, options: dict) -> dict:
    """Dry run: the linear entries the estimate needs and the catalogue lacks, designed without
    storing them (by key)."""
    planned = [r for r in rows if r.status == "planned"]
    entries = {}
    for row in {r.key: r for r in planned}.values():
        _say(options.get("progress", True),
             f"dry run: designing {row.family} {row.key} in memory for the range estimate")
        task = Task(index=row.segment, family=row.family, parameters=row.parameters, key=row.key,
                    options={**row.options, "linear_solver": options.get("linear_solver", "auto"),
                             "estimate_accuracy": False})
        entries[row.key] = designer.design(task)
    return entries


@contextlib.contextmanager
def _entries(catalogue, memory: dict):
    """``load(key)``: an entry from ``memory`` first, else from the catalogue (opened once, on
    first need)."""
    with contextlib.ExitStack() as stack:
        opened = []

        def load(key: str):
            if key in memory:
                return memory[key]
            if not opened:
                opened.append(stack.enter_context(open_catalogue(catalogue)))
            return opened[0].load(key)
        yield load


def needed_level(estimate, fitted) -> tuple[float, float]:
    """How far into an entry's sampled box (``fitted``, its :class:`~vertebra.core.energy.EnergyRange`)
    the scene's estimated range ``estimate`` (:class:`~vertebra.designer.scene_range.SegmentRange`,
    None: unknown) reaches, in the measure of :func:`~vertebra.designer.energy_fit.load_levels`:
    ``(load level, pressure level)``, the largest estimated load group over the fitted load bound
    and estimated pressure over the top fitted pressure (1: the whole box; inf: an unbounded
    pressure; no estimate: beyond the box in both)."""
    if estimate is None:
        return math.inf, math.inf
    bounds = np.asarray(fitted.load_upper, dtype=float)
    loads = np.maximum(np.abs(estimate.load_lower), np.abs(estimate.load_upper))
    load = float(np.max(np.where(bounds > 0, loads / np.where(bounds > 0, bounds, 1.0), 0.0)))
    pressure = 0.0
    for cavity, (_, high) in estimate.pressures.items():
        if cavity < fitted.n_cavities and float(fitted.pressure_upper[cavity]) > 0:
            pressure = max(pressure, high / float(fitted.pressure_upper[cavity]))
    return load, pressure


def fit_refusal(energy, level: tuple[float, float], max_fit_error: float) -> str | None:
    """Why an entry's energy cannot serve a scene that needs its sampled box up to ``level``
    (:func:`needed_level`: load and pressure levels): its held-out load error over that part of
    the box (:func:`~vertebra.designer.energy_fit.error_up_to`; entries without the per-sample
    errors: over the whole box) exceeds ``max_fit_error`` — None when it does not."""
    held = energy.fit_error.get("held_out", {}) if isinstance(energy.fit_error, dict) else {}
    rows = held.get("by_level") or []
    found = error_up_to(rows, *level) if rows else None
    if found is not None:
        error, count = found
        where = ("its whole sampled box" if count == len(rows) else
                 f"the {count} of its {len(rows)} held-out samples within the part of its sampled box the scene "
                 f"needs (loads to {min(level[0], 1.0):.2g} of its bounds"
                 + (f", pressures to {min(level[1], 1.0):.2g}" if energy.range.n_cavities else "") + ")")
    elif "load_max" in held:
        error, where = float(held["load_max"]), "its whole sampled box"
    else:
        return None
    if not error > max_fit_error:
        return None
    model = energy.material.get("model") if isinstance(energy.material, dict) else None
    why = (" (St Venant–Kirchhoff softens towards a compressive limit point, which the polynomial does not "
           "follow)" if model == "svk" else "")
    return (f"its energy fit misses its held-out samples by up to {error:.3g} of the load range over {where} "
            f"(rms over the box {held.get('load_rms', float('nan')):.3g}), more than the {max_fit_error:.3g} "
            f"allowed{why}: results there would carry errors of that order. Narrow the sampled box "
            f"(sampling = {{ strain = … }} on the segment, or bending/shear/axial), raise sampling.degree, choose "
            f"material = \"neo_hookean\", or accept the fit with --max-fit-error {error:.2g} "
            f"(Python: max_fit_error=)")


def _fit_checks(rows, estimate, catalogue, max_fit_error: float) -> dict:
    """Per nonlinear segment whose entry is in the catalogue: the refusal of :func:`fit_refusal`
    (segment → reason), for the part of the entry's box the scene's estimate needs."""
    ready = [r for r in rows if r.status in ("reused", "designed")]
    if not ready or not math.isfinite(max_fit_error):
        return {}
    with _entries(catalogue, {}) as load:
        energies = {key: load(key).energy for key in {r.key for r in ready}}
    out = {}
    for row in ready:
        energy = energies[row.key]
        if energy is None:
            continue
        segment = None if estimate is None else estimate.segments[row.segment]
        reason = fit_refusal(energy, needed_level(segment, energy.range), max_fit_error)
        if reason is not None:
            out[row.segment] = f"entry {row.key}: {reason}"
    return out


def _coverage(rows, estimate, catalogue) -> dict:
    """Per nonlinear segment whose entry is in the catalogue: where the scene's estimated range
    leaves the range the entry was actually fitted on (paths stopped early, pressures clamped
    below an inflation limit point, settings the scene gave)."""
    ready = [r for r in rows if r.status in ("reused", "designed")]
    if estimate is None or not ready:
        return {}
    out = {}
    with _entries(catalogue, {}) as load:
        fitted = {key: load(key).energy.range for key in {r.key for r in ready}}
    for row in ready:
        missed = uncovered(estimate.segments[row.segment], fitted[row.key])
        if missed:
            out[row.segment] = tuple(f"the entry's fitted range misses the scene's estimate: {m}" for m in missed)
    return out
