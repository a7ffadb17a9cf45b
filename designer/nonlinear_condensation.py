"""Nonlinear condensation: a segment's energy ψ(s, p) sampled with its nonlinear FE and fitted.

:func:`condense_energy` runs the whole step for one segment whose linear entry (its
compliance on the same mesh) is known: the pressure ramp to the inflation limit point (for
segments with cavities), the loading paths through an executor, the range, the fit and its
held-out error (:mod:`designer.energy_sampling`, :mod:`designer.energy_fit`). The result is
the :class:`core.energy.EnergyFit` a nonlinear catalogue entry carries.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, replace

import numpy as np

from vertebra.designer.energy_fit import (FitResult, SegmentSymmetry, Samples, convexity, fit_energy, fit_errors,
                                          inflation_errors, symmetry_group)
from vertebra.designer.energy_sampling import (LoadBox, PathTask, PressureTask, SamplingSettings, load_box,
                                               path_endpoints, pressure_path, run_paths, run_pressure_ramp)
from vertebra.designer.executors import Crash, make_executor
from vertebra.designer.keys import NONLINEAR_VERSION, SegmentDesign
from vertebra.designer.linear import LinearCondenser
from vertebra.designer import multifidelity
from vertebra.designer.nonlinear import NonlinearSegment
from vertebra.designer.nonlinear.fe_newton import NewtonSettings
from vertebra.designer.nonlinear.fe_segment import SegmentSettings
from vertebra.designer.threads import pin_blas_threads
from vertebra.core.energy import EnergyFit, EnergyRange, group_coordinates, linear_terms
from vertebra.core.errors import ConvergenceError
from vertebra.store.entry import SegmentEntry

#: margin added around the sampled poses when stating the range (fraction of each group's width)
POSE_MARGIN = 0.02
#: Newton tolerance (residual / force scale) of the sampling's FE solves. A response takes the
#: remaining interior residual out to first order (``fe_segment._PoseProblem.converged``), so its
#: wrench, volumes and ψ are exact to O(rtol²) and its tangent to O(rtol) (700× below the fits'
#: tangent errors): 1e-5 instead of the FE's 1e-10 saves about one Newton iteration (an
#: assembly and a solve) per sample, and with the predictor's second-order term
#: (``fe_segment._PoseProblem._second_order``) many samples along a path need none (measured on
#: a P2 rod, 1.1k DoFs, 8 paths: 4.5 assemblies per Newton solve at 1e-10, 3.6 at 1e-6, 3.1 at
#: 1e-5 with the second-order term)
SAMPLE_RTOL = 1e-5


def _say(progress, message: str) -> None:
    if progress is not None:
        progress(message)


def material_constants(material: str, parameters: dict) -> dict:
    """The ``material`` record of an energy: model name and its constants (neo-Hooke as C10, D1)."""
    E, nu = parameters["youngs_modulus"], parameters["poisson_ratio"]
    mu, bulk = E / (2 * (1 + nu)), E / (3 * (1 - 2 * nu))
    out = {"model": material, "youngs_modulus": E, "poisson_ratio": nu, "shear_modulus": mu, "bulk_modulus": bulk}
    if material == "neo_hookean":
        out.update(C10=mu / 2, D1=2 / bulk)
    return out


@dataclass(frozen=True)
class FamilySolid:
    """ModelSpec (:class:`designer.energy_sampling.ModelSpec`) of a designed segment's nonlinear FE:
    the family's mesh (gmsh meshes deterministically, so it is the linear entry's mesh) with a
    material of :data:`designer.nonlinear.MATERIALS`, its solves converged to :data:`SAMPLE_RTOL`."""

    family: str
    parameters: str                  # canonical JSON of the canonical parameters
    mesh_size: float
    order: int
    material: str
    linear_solver: str = "auto"

    def key(self) -> str:
        return json.dumps([self.family, self.parameters, self.mesh_size, self.order, self.material,
                           self.linear_solver])

    def build(self):
        pin_blas_threads(1)
        settings = SegmentSettings(newton=NewtonSettings(rtol=SAMPLE_RTOL))
        return NonlinearSegment.from_family(self.family, json.loads(self.parameters), self.material,
                                            mesh_size=self.mesh_size, order=self.order,
                                            linear_solver=self.linear_solver, settings=settings)


@dataclass
class Condensed:
    """The fitted energy and how it was obtained."""

    energy: EnergyFit
    samples: Samples
    held_out: np.ndarray
    timings: dict


def _results(executor, function, items):
    """The results of ``function`` over ``items`` through ``executor``, as they complete; a
    worker that crashed is an error (the sampling has no use for part of its paths)."""
    for _, result in executor.map_unordered(function, items):
        if isinstance(result, Crash):
            raise ConvergenceError(f"nonlinear sampling: a worker failed: {result.error_type}: {result.message}")
        yield result


def pressure_range(executor, spec, entry, linear, settings: SamplingSettings, youngs_modulus: float,
                   progress=None, cavity: int = 0):
    """``(largest sampled pressure, inflation limit point or None, fold pressure or None, free pose at
    the top pressure, diagnostics)``: a ramp of ``cavity``'s pressure with the top free (by the
    family's symmetry every cavity behaves alike) up to the requested pressure, or up to the
    Young's modulus when none is requested. Without a limit point below the ramp, the fold
    map uses where the ramp's last steps put it (if beyond the sampled pressures)."""
    K, S, V = linear
    largest = settings.pressure / settings.limit_fraction if settings.pressure else youngs_modulus
    task = PressureTask(spec=spec, rest_translation=tuple(entry.rest_translation),
                        rest_volumes=tuple(entry.cavity_volumes), stiffness=tuple(K.ravel()),
                        mixed=tuple((-K @ S).ravel()), cavity=cavity, rest_compliance=float(V[cavity, cavity]),
                        largest=largest, first_step=largest / 16.0, min_step=largest / 512.0)
    _say(progress, f"pressure ramp of cavity {cavity} up to {largest:.4g} Pa (inflation limit point search)")
    outcome = next(_results(executor, run_pressure_ramp, [task]))
    if outcome.limit is not None:
        top = settings.limit_fraction * outcome.limit
        if settings.pressure:
            top = min(top, settings.pressure)
        _say(progress, f"inflation limit point near {outcome.limit:.4g} Pa ({outcome.reason}); "
                       f"pressures sampled up to {top:.4g} Pa")
    else:
        top = settings.pressure or largest
        _say(progress, f"no limit point below {largest:.4g} Pa; pressures sampled up to {top:.4g} Pa")
    fold = outcome.limit if outcome.limit is not None else outcome.fold
    if fold is not None and not fold > 1.02 * top:
        fold = None
    return top, outcome.limit, fold, outcome.free_pose, {
        "ramp_solves": outcome.solves, "ramp_s": outcome.seconds, "ramp_reached": outcome.reached,
        "ramp_reason": outcome.reason, "ramp_fold_estimate": outcome.fold}


def _tasks(spec, entry, linear, box: LoadBox, caps, endpoints, settings, workers: int,
           indices=None) -> list[PathTask]:
    """The tasks following the paths to ``endpoints`` (numbered ``indices``, by default their rows)."""
    K, S, _ = linear
    indices = list(range(len(endpoints)) if indices is None else indices)
    per_task = max(1, math.ceil(len(indices) / (3 * max(1, workers))))
    tasks = []
    for lo in range(0, len(indices), per_task):
        paths = tuple((i, tuple(endpoints[i])) for i in indices[lo:lo + per_task])
        tasks.append(PathTask(spec=spec, rest_translation=tuple(entry.rest_translation),
                              rest_volumes=tuple(entry.cavity_volumes), stiffness=tuple(K.ravel()),
                              mixed=tuple((-K @ S).ravel()), box=box, caps=tuple(caps), paths=paths,
                              steps=settings.steps))
    return tasks


def sampled_range(samples: Samples, box: LoadBox, load_fraction: float, limit: float | None) -> EnergyRange:
    """The range of a fit: the sampled poses' bounding box in group coordinates (plus
    :data:`POSE_MARGIN`), the load box scaled by ``load_fraction`` (< 1 when paths stopped
    early on a failure), the sampled pressures."""
    groups = group_coordinates(samples.strain)
    lower = np.array([0.0, min(0.0, groups[:, 1].min()), 0.0, min(0.0, groups[:, 3].min())])
    upper = np.array([groups[:, 0].max(), max(0.0, groups[:, 1].max()), groups[:, 2].max(),
                      max(0.0, groups[:, 3].max())])
    width = np.maximum(upper - lower, 1e-300)
    lower = lower - POSE_MARGIN * width * np.array([0, 1, 0, 1])
    upper = upper + POSE_MARGIN * width
    bounds = load_fraction * box.group_bounds()
    m = samples.n_cavities
    p_top = samples.pressure.max(axis=0) if m else np.zeros(0)
    return EnergyRange(pose_lower=lower, pose_upper=upper, load_lower=np.array([0.0, -bounds[1], 0.0, -bounds[3]]),
                       load_upper=bounds, pressure_lower=np.zeros(m), pressure_upper=p_top, limit_pressure=limit)


def condense_energy(entry, spec, *, radius: float, youngs_modulus: float, symmetry: SegmentSymmetry,
                    material: dict, settings: SamplingSettings | None = None, executor: str = "serial",
                    workers: int | None = None, scheduler: str | None = None, progress=None,
                    ramp: tuple | None = None) -> Condensed:
    """Sample and fit the energy of the segment of the linear ``entry`` (same mesh) with the
    nonlinear FE described by ``spec`` (:class:`designer.energy_sampling.ModelSpec`).
    ``ramp``: the outcome of :func:`pressure_range` run already (on another mesh of the segment:
    a multi-fidelity entry's pressures are those of its own mesh), instead of running it here."""
    m = entry.n_cavities
    settings = (settings or SamplingSettings()).resolved(m, material["model"])
    start = time.perf_counter()
    linear = linear_terms(entry.compliance, entry.rest_translation)
    K = linear[0]
    length = float(np.linalg.norm(entry.rest_translation))
    timings = {}
    pressurised = settings.pressurised(m)
    with make_executor(executor, workers=workers, scheduler=scheduler) as pool:
        pressure_info, limit, fold_estimate, p_top, free_pose = {}, None, None, 0.0, np.zeros(4)
        if pressurised and ramp is not None:
            p_top, limit, fold_estimate, free_pose, pressure_info = ramp
        elif pressurised:
            p_top, limit, fold_estimate, free_pose, pressure_info = pressure_range(
                pool, spec, entry, linear, settings, youngs_modulus, progress, cavity=pressurised[0])
        elif m:
            _say(progress, f"no cavity pressurised (sampling.cavities): sampled at zero pressure, "
                           f"no inflation-limit search")
        box, caps = load_box(K, length, radius, settings, pressure=p_top, free_pose=free_pose)
        endpoints, held_paths = path_endpoints(m, settings)
        tasks = _tasks(spec, entry, linear, box, caps, endpoints, settings, pool.workers)
        _say(progress, f"sampling {len(endpoints)} loading paths × {settings.steps} steps in {len(tasks)} tasks "
                       f"({pool.name} executor, {pool.workers} worker(s)); bending up to {caps[2]:.3g} rad, "
                       f"twist {caps[3]:.3g} rad")
        outcomes, done, t0 = [], 0, time.perf_counter()
        for result in _results(pool, run_paths, tasks):
            outcomes.append(result)
            done += len(result.reached)
            elapsed = time.perf_counter() - t0
            left = f", about {elapsed * (len(endpoints) - done) / done:.0f} s left" if done < len(endpoints) else ""
            _say(progress, f"  {done}/{len(endpoints)} paths, {sum(o.solves for o in outcomes)} FE solves, "
                           f"{elapsed:.1f} s{left}")
    timings["sampling_s"] = time.perf_counter() - start
    parts = [o.samples for o in outcomes if o.samples is not None]
    if not parts:
        raise ConvergenceError("nonlinear sampling: no FE solve converged")
    samples = Samples.concatenate(parts)
    reached = {i: f for o in outcomes for i, f in o.reached.items()}
    stopped = {i: r for o in outcomes for i, r in o.stopped.items()}
    failed = [reached[i] for i, reason in stopped.items() if not reason.startswith("pose")]
    load_fraction = min([1.0] + [max(f, 1.0 / settings.steps) for f in failed])
    if stopped:
        _say(progress, f"{len(stopped)} path(s) stopped early: " + "; ".join(
            f"#{i} at {reached[i]:.2f} ({r})" for i, r in sorted(stopped.items())[:4]))
    energy_range = sampled_range(samples, box, load_fraction, limit)
    scales = np.concatenate([
        [energy_range.pose_upper[0]] * 2,
        [max(abs(energy_range.pose_lower[1]), energy_range.pose_upper[1])],
        [energy_range.pose_upper[2]] * 2,
        [max(abs(energy_range.pose_lower[3]), energy_range.pose_upper[3])],
        [p_top if p_top > 0 else youngs_modulus] * m])   # no pressure sampled: any finite scale
    group = symmetry_group(symmetry, settings.degree)
    held_out = held_paths[samples.path]
    t1 = time.perf_counter()
    fold = fold_estimate if (pressurised and settings.fold) else None
    if fold is not None:                # the pressures' scale in the fold variable w(p)
        scales[6:] = 2.0 * fold * (1.0 - math.sqrt(1.0 - p_top / fold))
    result = fit_energy(samples, linear, degree=settings.degree,
                        pressure_degree=settings.pressure_degree if pressurised else 0,
                        group=group, scales=scales, held_out=held_out, hessian_weight=settings.hessian_weight,
                        fold=fold)
    volume_scale = float(np.abs(samples.pressure_gradient).max()) if pressurised else None
    bounds = energy_range.load_upper
    top = samples.pressure.max(axis=0) if m else None
    errors = {"held_out": fit_errors(result, linear, samples.take(held_out), bounds, volume_scale, top, by_level=True)
              if held_out.any() else {"samples": 0},
              "training": fit_errors(result, linear, samples.take(~held_out), bounds, volume_scale),
              "convexity_min_relative_eigenvalue": convexity(result, linear, samples.variables()),
              "unknowns": result.unknowns}
    timings["fit_s"] = time.perf_counter() - t1
    held = errors["held_out"]
    _say(progress, f"fit of degree {settings.degree}: {result.unknowns} unknowns, {len(result.exponents)} terms; "
                   f"held-out load error {held.get('load_max', float('nan')):.3g} of the range "
                   f"(linear {held.get('linear_load_max', float('nan')):.3g}); convexity "
                   f"{errors['convexity_min_relative_eigenvalue']:.3g}")
    sampling = {"settings": settings.describe(), "symmetry": symmetry.describe(), "group_order": len(group),
                "paths": int(len(endpoints)), "held_out_paths": int(held_paths.sum()), "samples": int(samples.size),
                "solves": int(sum(o.solves for o in outcomes)),
                "stopped": {str(i): r for i, r in sorted(stopped.items())}, "load_fraction": load_fraction,
                "load_box": {"lateral": box.lateral, "axial": box.axial, "bending": box.bending,
                             "twist": box.twist, "pressure": box.pressure},
                "pose_caps": caps.tolist(), **pressure_info}
    energy = EnergyFit(exponents=result.exponents, coefficients=result.coefficients, scales=result.scales,
                       range=energy_range, fit_error=errors, material=material, sampling=sampling, fold_pressure=fold)
    timings["total_s"] = time.perf_counter() - start
    return Condensed(energy=energy, samples=samples, held_out=held_out, timings=timings)


def check_on_mesh(entry, condensed: Condensed, spec, settings: SamplingSettings, *, executor: str = "serial",
                  workers: int | None = None, scheduler: str | None = None, progress=None,
                  sampled=None) -> tuple[EnergyFit, dict]:
    """Multi-fidelity: the energy ``condensed`` fitted on a coarser mesh (its ψ_nl, on that mesh's
    linear part), checked on ``entry``'s mesh (the FE of ``spec``). ψ = ψ_lin of ``entry`` (its
    exact compliance: stiffness, cavity coupling and volume compliance) + the coarse ψ_nl.
    ``settings.check_paths`` of the sampling's loading paths (its held-out ones first), and for
    a segment with a pressurised cavity the path inflating it alone up to the top pressure, are
    followed with the FE of ``entry``'s mesh through the same load box; their samples give the
    entry's held-out error (``fit_error["held_out"]``, the one ``prepare --max-fit-error``
    reads), the coarse sampling's own one stays as ``nonlinear_mesh_held_out``. On the
    inflation path, the free inflation response's errors (:func:`designer.energy_fit.inflation_errors`)
    on the entry's mesh and — with ``sampled``, the coarse entry — on the coarser mesh are
    recorded as ``entry_mesh_check["inflation"]``. The range is the
    coarse sampling's; its pressures, fold map and inflation limit point come from the ramp on
    the entry's mesh (:class:`NonlinearCondenser`).
    Returns ``(energy, {"check_s": seconds})`` (the seconds in the entry's timings, not in its
    energy: the same design gives the same energy)."""
    start = time.perf_counter()
    coarse = condensed.energy
    m = entry.n_cavities
    linear = linear_terms(entry.compliance, entry.rest_translation)
    endpoints, held_paths = path_endpoints(m, settings)
    order = np.concatenate([np.flatnonzero(held_paths), np.flatnonzero(~held_paths)])
    chosen = [int(i) for i in order[:settings.check_paths]]
    inflation = pressure_path(m, settings)
    if inflation is not None and inflation not in chosen:
        chosen.append(inflation)
    box = LoadBox(**coarse.sampling["load_box"])
    caps = np.array(coarse.sampling["pose_caps"], dtype=float)
    with make_executor(executor, workers=workers, scheduler=scheduler) as pool:
        tasks = _tasks(spec, entry, linear, box, caps, endpoints, settings, pool.workers, indices=chosen)
        _say(progress, f"check on the entry's mesh (h = {spec.mesh_size:g} m): {len(chosen)} loading path(s) "
                       f"× {settings.steps} steps ({pool.name} executor, {pool.workers} worker(s))")
        outcomes = list(_results(pool, run_paths, tasks))
    parts = [o.samples for o in outcomes if o.samples is not None]
    if not parts:
        raise ConvergenceError(f"multi-fidelity check: no FE solve converged on the entry's mesh "
                               f"(h = {spec.mesh_size:g} m) along the coarse sampling's paths")
    samples = Samples.concatenate(parts)
    stopped = {i: r for o in outcomes for i, r in o.stopped.items()}
    result = FitResult(exponents=coarse.exponents, coefficients=coarse.coefficients, scales=coarse.scales,
                       unknowns=int(coarse.fit_error.get("unknowns", 0)), errors={}, fold=coarse.fold_pressure)
    pressurised = settings.pressurised(m)
    coarse_samples = condensed.samples
    volume_scale = float(np.abs(coarse_samples.pressure_gradient).max()) if pressurised else None
    top = coarse_samples.pressure.max(axis=0) if m else None
    held = fit_errors(result, linear, samples, coarse.range.load_upper, volume_scale, top, by_level=True)
    fit_error = {**coarse.fit_error, "held_out": held, "nonlinear_mesh_held_out": coarse.fit_error["held_out"],
                 "convexity_min_relative_eigenvalue": convexity(result, linear, coarse_samples.variables())}
    seconds = time.perf_counter() - start
    check = {"mesh_size": float(spec.mesh_size), "paths": chosen, "samples": int(samples.size),
             "solves": int(sum(o.solves for o in outcomes)), "stopped": {str(i): r for i, r in sorted(stopped.items())}}
    if inflation is not None:
        cavity = pressurised[0]
        check["inflation"] = {"entry_mesh": inflation_errors(result, linear, samples.take(samples.path == inflation),
                                                             cavity)}
        if sampled is not None:
            own = coarse_samples.take(coarse_samples.path == inflation)
            check["inflation"]["nonlinear_mesh"] = inflation_errors(
                result, linear_terms(sampled.compliance, sampled.rest_translation), own, cavity)
        fine = check["inflation"]["entry_mesh"]
        if fine.get("samples"):
            _say(progress, f"free inflation response on the entry's mesh: pose error {fine['pose_max']:.3g}, "
                           f"volume growth error {fine['volume_max']:.3g} (relative)")
    _say(progress, f"held-out load error on the entry's mesh {held['load_max']:.3g} of the range (linear entry "
                   f"{held['linear_load_max']:.3g}; on the nonlinear mesh "
                   f"{coarse.fit_error['held_out'].get('load_max', float('nan')):.3g})"
                   + (f"; {len(stopped)} path(s) stopped early" if stopped else ""))
    sampling = {**coarse.sampling, "entry_mesh_check": check}
    return replace(coarse, fit_error=fit_error, sampling=sampling), {"check_s": seconds}


@dataclass(frozen=True)
class NonlinearCondenser:
    """The condenser of a hyperelastic material (:data:`designer.nonlinear.MATERIALS`): the
    ``linear`` condenser's entry of the design (its compliance on the same mesh), with the
    energy :func:`condense_energy` samples and fits with the design's sampling settings, the FE
    solves running on ``executor`` (``serial``, ``local`` with ``workers``, ``dask`` with
    ``scheduler``). With ``sampling.nonlinear_mesh_size`` (multi-fidelity; chosen by the design
    above ``designer.multifidelity.AUTO_DOFS``), the energy is sampled and fitted on that coarser
    mesh of the segment (its ψ_nl on its own linear part), joined to the entry's exact linear
    part and checked on the entry's mesh (:func:`check_on_mesh`); the inflation-limit ramp runs
    on the entry's mesh. A chosen mesh (or one with ``sampling.check_tolerance``) whose check
    fails (``designer.multifidelity.check_verdict``) is dropped: the entry is sampled on its own
    mesh, as without a nonlinear mesh, and records why."""

    linear: LinearCondenser
    executor: str = "serial"
    workers: int | None = None
    scheduler: str | None = None

    def _ramp(self, entry, spec, settings, youngs_modulus, progress):
        """The inflation-limit ramp on ``entry``'s mesh (None without a pressurised cavity)."""
        pressurised = settings.pressurised(entry.n_cavities)
        if not pressurised:
            return None
        linear = linear_terms(entry.compliance, entry.rest_translation)
        with make_executor(self.executor, workers=self.workers, scheduler=self.scheduler) as pool:
            ramp = pressure_range(pool, spec, entry, linear, settings, youngs_modulus, progress, cavity=pressurised[0])
        return (*ramp[:4], {**ramp[4], "ramp_mesh_size": float(spec.mesh_size)})

    def _on_coarser_mesh(self, design, entry, fine, common, timings, progress):
        """``(energy, ramp, fallback)`` of a multi-fidelity design: the fine ramp, the coarse
        sampling and fit, the check on ``entry``'s mesh. ``energy`` is None when a chosen mesh
        (or one with a ``check_tolerance``) failed its check: ``fallback`` says why."""
        fam, p, settings = design.family, design.parameters, design.sampling
        coarse_h = settings.nonlinear_mesh_size
        resolved = settings.resolved(entry.n_cavities, design.material)
        how = "chosen for this mesh" if settings.nonlinear_mesh_chosen else "asked for"
        _say(progress, f"{fam.name}: the nonlinear part on a coarser mesh (h = {coarse_h:g} m, {how}), the "
                       f"linear part from this one (h = {design.mesh_size:g} m, {entry.mesh['dofs']} dofs)")
        t0 = time.perf_counter()
        ramp = self._ramp(entry, fine, resolved, p["youngs_modulus"], progress)
        if ramp is not None:
            timings["ramp_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        coarse_linear = replace(self.linear, estimate_accuracy=False, estimate_alongside=False)
        sampled = coarse_linear.condense(replace(design, mesh_size=coarse_h), progress)
        timings["nonlinear_mesh_s"] = time.perf_counter() - t0
        _say(progress, f"{fam.name}: nonlinear condensation with the {design.material} material on the "
                       f"coarser mesh ({sampled.mesh['dofs']} dofs)")
        condensed = condense_energy(sampled, replace(fine, mesh_size=sampled.mesh["mesh_size"]), ramp=ramp, **common)
        timings.update({k: v for k, v in condensed.timings.items() if k != "total_s"})
        energy, checked = check_on_mesh(entry, condensed, fine, resolved, executor=self.executor,
                                        workers=self.workers, scheduler=self.scheduler, progress=progress,
                                        sampled=sampled)
        timings.update(checked)
        coarse_mesh = {k: sampled.mesh[k] for k in ("mesh_size", "dofs", "elements", "nodes", "order")}
        if settings.nonlinear_mesh_chosen:
            estimate = multifidelity.estimated_dofs(fam, p, design.mesh_size, design.order)
            coarse_mesh.update(chosen=True, estimated_entry_dofs=estimate, auto_dofs=multifidelity.AUTO_DOFS)
        check = energy.sampling["entry_mesh_check"]
        if not (settings.nonlinear_mesh_chosen or settings.check_tolerance is not None):
            return replace(energy, sampling={**energy.sampling, "nonlinear_mesh": coarse_mesh}), ramp, None
        tolerance = settings.check_tolerance
        passed, why = multifidelity.check_verdict({**check, "held": energy.fit_error["held_out"]},
                                                  energy.fit_error["nonlinear_mesh_held_out"], tolerance)
        verdict = {"passed": passed, "why": why, "tolerance": tolerance,
                   "factor": None if tolerance is not None else multifidelity.CHECK_FACTOR}
        check = {**check, "verdict": verdict}
        _say(progress, f"{fam.name}: the check on this mesh {'passed' if passed else 'failed'}: {why}"
             + ("" if passed else "; sampling this mesh instead (the coarser mesh's fit is dropped)"))
        if passed:
            return replace(energy, sampling={**energy.sampling, "nonlinear_mesh": coarse_mesh,
                                             "entry_mesh_check": check}), ramp, None
        return None, ramp, {"nonlinear_mesh": coarse_mesh, "entry_mesh_check": check,
                            "held_out": energy.fit_error["held_out"],
                            "nonlinear_mesh_held_out": energy.fit_error["nonlinear_mesh_held_out"]}

    def condense(self, design: SegmentDesign, progress=None) -> SegmentEntry:
        entry = self.linear.condense(design, progress)
        fam, p = design.family, design.parameters
        timings = dict(entry.timings)
        options = dict(family=fam.name, parameters=json.dumps(p, sort_keys=True), order=design.order,
                       material=design.material, linear_solver=self.linear.linear_solver)
        fine = FamilySolid(mesh_size=entry.mesh["mesh_size"], **options)
        common = dict(radius=fam.outer_radius(p), youngs_modulus=p["youngs_modulus"], symmetry=fam.symmetry(p),
                      material=material_constants(design.material, p), settings=design.sampling,
                      executor=self.executor, workers=self.workers, scheduler=self.scheduler, progress=progress)
        nonlinear = {"executor": self.executor, "workers": self.workers, "version": NONLINEAR_VERSION}
        energy, ramp, fallback = None, None, None
        if design.sampling is not None and design.sampling.nonlinear_mesh_size is not None:
            energy, ramp, fallback = self._on_coarser_mesh(design, entry, fine, common, timings, progress)
            if energy is not None:
                nonlinear["nonlinear_mesh_size"] = float(design.sampling.nonlinear_mesh_size)
        if energy is None:
            _say(progress, f"{fam.name}: nonlinear condensation with the {design.material} material")
            t0 = time.perf_counter()
            condensed = condense_energy(entry, fine, ramp=ramp, **common)
            energy = condensed.energy
            timings.update({k: v for k, v in condensed.timings.items() if k != "total_s"})
            if fallback is not None:
                timings["fallback_s"] = time.perf_counter() - t0
                energy = replace(energy, sampling={**energy.sampling, "nonlinear_mesh_fallback": fallback})
        timings["total_s"] = time.perf_counter() - design.started
        provenance = {**entry.provenance, "nonlinear": nonlinear}
        return replace(entry, energy=energy, timings={k: float(v) for k, v in timings.items()},
                       provenance=provenance)
