"""Reachable workspace: effector positions over actuations sampled within their bounds.

``sample_workspace(model, n)`` draws ``n`` actuations quasi-randomly inside the actuator
bounds (a scrambled Sobol or Halton sequence, seeded), orders them so that each forward
solve starts near the equilibrium of an already solved neighbour, solves them all and
returns a :class:`Workspace`: the effector point clouds with per-sample diagnostics
(converged, Newton iterations, warm start) and every failure by sample. A solve that fails
is recorded, never raised.

Solve order
    Nearness is measured where it matters to Newton: in the linear response of the trunk at
    rest, ``q ≈ K⁻¹ B λ`` (translations in m, rotations times the trunk length), projected on
    its principal directions. Orderings are registered in :data:`ORDERINGS`:

    * ``"tree"`` (default): the minimum spanning tree of the k-nearest-neighbour graph in that
      response space, visited depth first from the least deformed sample; each sample starts
      from its tree parent. Every warm start is a shortest available edge, and a parent with
      several children serves them all.
    * ``"chain"``: a greedy nearest-neighbour chain in the same space (each sample starts from
      the previous one); its last links are long jumps between leftover samples.
    * ``"sampled"``: the order the sequence drew them in (neighbours are far apart).

Warm start
    A sample does not start from its parent's equilibrium ``q_p`` itself but from the Euler
    predictor along the equilibrium path, ``q_p ⊕ K_p⁻¹ B_p (λ − λ_p)`` (the tangent of the
    parent's equilibrium, factored once per parent): Newton's own first step from ``q_p``
    uses the tangent at the new load, which is not the path's derivative, and needs about two
    more iterations on the paper's 16-tendon robot.

``benchmarks/bench_workspace.py`` measures orderings and predictor against each other.

Only numpy and scipy are imported; pictures are drawn by :mod:`vertebra.solver.workspace_plot`.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from vertebra.solver.hull import Hull, convex_hull
from vertebra.solver.workspace_order import ORDERINGS, SolveOrder, response_coordinates
from vertebra.core.errors import ConvergenceError, OptionError, SceneError

SAMPLERS = ("sobol", "halton")
MAX_SAMPLES = 1_000_000   # samples of one workspace (~7 minutes of solves at 0.4 ms each)

# what a forward solve may raise when a sample's equilibrium cannot be found: recorded, not raised
SOLVE_FAILURES = (ConvergenceError, FloatingPointError, ValueError, np.linalg.LinAlgError)


# ---------------------------------------------------------------------------- sampling
def actuation_box(model) -> tuple[np.ndarray, np.ndarray]:
    """The actuator bounds as a finite box; a SceneError names an actuator without one."""
    lower, upper = (np.asarray(b, float) for b in model.actuator_bounds)
    if lower.size == 0:
        raise SceneError("no [[cable]] or [[chamber]]: there is no actuation to sample",
                         file=model.scene.source, field="cable")
    for k in np.flatnonzero(~(np.isfinite(lower) & np.isfinite(upper))):
        if k < model.n_cables:
            which = "stroke" if model.trunk.actuators.stroke_driven[k] else "tension"
            name, table = model.actuator_names[k], f"cable[{k}]"
        else:
            name, table, which = model.actuator_names[k], f"chamber[{k - model.n_cables}]", "pressure"
        bound = f"min_{which}" if not np.isfinite(lower[k]) else f"max_{which}"
        raise SceneError(f"{name!r} needs a finite {bound} to sample its workspace",
                         file=model.scene.source, field=f"{table}.{bound}")
    return lower, upper


def sample_unit(n_samples: int, dimension: int, *, method: str = "sobol", seed: int = 0) -> np.ndarray:
    """``n_samples`` scrambled quasi-random points in the unit cube ``[0, 1)^dimension``."""
    from scipy.stats import qmc

    if method not in SAMPLERS:
        raise OptionError(f"unknown sampler {method!r}; choose one of {', '.join(SAMPLERS)}", field="method")
    if isinstance(n_samples, bool) or not isinstance(n_samples, (int, np.integer)) or n_samples < 1:
        raise OptionError(f"need at least one sample (a whole number), got {n_samples!r}", field="samples")
    if n_samples > MAX_SAMPLES:
        raise OptionError(f"at most {MAX_SAMPLES:,} samples; got {n_samples:,}", field="samples")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))
                             or not 0 <= seed < 2**63):
        raise OptionError(f"expected a whole number from 0 to 2**63 - 1, got {seed!r}", field="seed")
    if method == "halton":
        return qmc.Halton(dimension, seed=seed).random(n_samples)
    # a prefix of a scrambled Sobol sequence is still low-discrepancy; only its balance
    # properties need a power of two, which is what scipy warns about
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return qmc.Sobol(dimension, seed=seed).random(n_samples)


def sample_actuations(model, n_samples: int, *, method: str = "sobol", seed: int = 0) -> np.ndarray:
    """``(n_samples, n_actuators)`` actuations inside the bounds (tensions N, a stroke-driven
    tendon's servo stroke m, pressures Pa)."""
    lower, upper = actuation_box(model)
    return lower + sample_unit(n_samples, lower.size, method=method, seed=seed) * (upper - lower)


# ---------------------------------------------------------------------------- results
@dataclass(frozen=True)
class EffectorCloud:
    """The converged samples of one effector: world points (m), or unit directions for an
    axis effector."""

    name: str
    kind: str                 # "point" | "direction"
    points: np.ndarray        # (m, 3)

    def __post_init__(self):
        if self.kind not in ("point", "direction"):
            raise ValueError(f"kind must be 'point' or 'direction', got {self.kind!r}")
        if self.points.ndim != 2 or self.points.shape[1] != 3:
            raise ValueError(f"points must be (m, 3), got shape {self.points.shape}")

    @property
    def lower(self) -> np.ndarray:
        return self.points.min(0) if len(self.points) else np.full(3, np.nan)

    @property
    def upper(self) -> np.ndarray:
        return self.points.max(0) if len(self.points) else np.full(3, np.nan)

    @property
    def centroid(self) -> np.ndarray:
        return self.points.mean(0) if len(self.points) else np.full(3, np.nan)

    def hull(self) -> Hull:
        return convex_hull(self.points)


@dataclass
class Workspace:
    """Forward solves of sampled actuations and the effector positions they reached.

    Arrays are in sample order (the order the sequence drew them). ``positions[i]`` is nan
    where sample ``i``'s solve failed; ``failures`` lists those samples with the error.
    ``beyond_bounds[i]``: sample ``i``'s equilibrium breaks a bound of the scene that the
    sampled box does not hold (a stroke, a volume growth, a stroke-driven tendon's tension;
    ``solver.bounds``); ``out_of_range[i]``: it leaves the range a link energy was fitted on.
    ``violations`` counts them by actuator and bound (``"t1: min_stroke"``) and by entry and
    quantity. With ``drop_outside`` the clouds leave those samples out (they stay in the arrays)."""

    actuator_names: list
    effector_names: list
    effector_is_axis: np.ndarray
    bounds: tuple                 # (lower, upper) of the actuation, N or Pa
    actuations: np.ndarray        # (n, n_act) N or Pa
    positions: np.ndarray         # (n, n_eff, 3) m (unit directions for axis effectors)
    converged: np.ndarray         # (n,) bool
    iterations: np.ndarray        # (n,) Newton iterations (load stages summed)
    warm: np.ndarray              # (n,) bool: started from another sample's equilibrium
    predicted: np.ndarray         # (n,) bool: ... moved along its path tangent (Euler predictor)
    failures: list                # [{"sample": i, "error": type name, "message": str}, ...]
    order: SolveOrder
    settings: dict
    timings: dict = field(default_factory=dict)
    beyond_bounds: np.ndarray | None = None     # (n,) bool (None: none)
    out_of_range: np.ndarray | None = None      # (n,) bool (None: none)
    violations: dict = field(default_factory=dict)
    drop_outside: bool = False

    def __post_init__(self):
        n = len(self.actuations)
        for name in ("beyond_bounds", "out_of_range"):
            if getattr(self, name) is None:
                setattr(self, name, np.zeros(n, bool))
        shapes = {"positions": (n, len(self.effector_names), 3), "converged": (n,), "iterations": (n,),
                  "warm": (n,), "predicted": (n,), "beyond_bounds": (n,), "out_of_range": (n,)}
        for name, shape in shapes.items():
            if getattr(self, name).shape != shape:
                raise ValueError(f"{name} has shape {getattr(self, name).shape}, expected {shape}")

    @property
    def n_samples(self) -> int:
        return len(self.actuations)

    @property
    def outside(self) -> np.ndarray:
        """(n,) bool: converged samples beyond a scene bound or a fitted range."""
        return self.converged & (self.beyond_bounds | self.out_of_range)

    @property
    def kept(self) -> np.ndarray:
        """(n,) bool: the samples of the clouds: converged, and inside unless ``drop_outside``."""
        return self.converged & ~self.outside if self.drop_outside else self.converged

    def cloud(self, name: str, *, outside: bool = False) -> EffectorCloud:
        """The positions of effector ``name`` at the :attr:`kept` samples (``outside``: at the
        converged samples beyond a bound or a fitted range instead)."""
        k = self.effector_names.index(name)
        return EffectorCloud(name, "direction" if self.effector_is_axis[k] else "point",
                             self.positions[self.outside if outside else self.kept, k])

    def clouds(self) -> list[EffectorCloud]:
        return [self.cloud(name) for name in self.effector_names]

    def summary(self) -> dict:
        """JSON-ready summary (no point lists: :func:`write_points` writes those)."""
        solved = self.iterations[self.converged]
        effectors = {}
        for cloud in self.clouds():
            entry = {"kind": cloud.kind, "count": int(len(cloud.points)),
                     "lower": _floats(cloud.lower), "upper": _floats(cloud.upper),
                     "centroid": _floats(cloud.centroid)}
            if cloud.kind == "point":
                hull = cloud.hull()
                entry["hull"] = {"dimension": hull.dimension, "volume": hull.volume, "area": hull.area}
            effectors[cloud.name] = entry
        return {
            "samples": self.n_samples,
            "converged": int(np.count_nonzero(self.converged)),
            "failed": int(self.n_samples - np.count_nonzero(self.converged)),
            "beyond_bounds": int(np.count_nonzero(self.converged & self.beyond_bounds)),
            "out_of_range": int(np.count_nonzero(self.converged & self.out_of_range)),
            "dropped": int(np.count_nonzero(self.converged & ~self.kept)),
            "violations": dict(self.violations),
            "settings": dict(self.settings),
            "actuators": {name: {"lower": _floats(self.bounds[0][k:k + 1])[0],
                                 "upper": _floats(self.bounds[1][k:k + 1])[0]}
                          for k, name in enumerate(self.actuator_names)},
            "effectors": effectors,
            "iterations": {"mean": float(solved.mean()) if solved.size else None,
                           "max": int(solved.max()) if solved.size else None,
                           "total": int(self.iterations.sum())},
            "warm_starts": int(np.count_nonzero(self.warm)),
            "predicted_starts": int(np.count_nonzero(self.predicted)),
            "failures": list(self.failures),
            "timing": {key: float(value) for key, value in self.timings.items()},
        }


def volume_text(volume: float) -> str:
    """A volume (m³) for people: in mm³, cm³ or m³, whichever gives a number from 1 to 1000
    (a hull of 2.6e-06 m³ reads "2.59 cm³")."""
    for unit, scale in (("mm³", 1e-9), ("cm³", 1e-6), ("dm³", 1e-3)):
        if abs(volume) < 1e3 * scale:
            return f"{volume / scale:.3g} {unit}"
    return f"{volume:.3g} m³"


def area_text(area: float) -> str:
    """An area (m²) for people: in mm², cm² or m²."""
    for unit, scale in (("mm²", 1e-6), ("cm²", 1e-4)):
        if abs(area) < 1e2 * scale:
            return f"{area / scale:.3g} {unit}"
    return f"{area:.3g} m²"


def _floats(values) -> list:
    return [float(v) if math.isfinite(v) else None for v in values]


# ---------------------------------------------------------------------------- solve
CHUNK = 256              # samples per task when solving in worker processes


@dataclass
class _Solved:
    """What solving some of the samples gave (indices into the whole sample set)."""

    samples: np.ndarray
    positions: np.ndarray
    converged: np.ndarray
    iterations: np.ndarray
    warm: np.ndarray
    predicted: np.ndarray
    failures: list
    cpu_s: float
    beyond_bounds: np.ndarray = None
    out_of_range: np.ndarray = None
    violations: dict = field(default_factory=dict)    # "<actuator>: <bound>" / "<entry>: <quantity>" → samples

    @classmethod
    def failed(cls, samples: np.ndarray, n_effectors: int, error: BaseException) -> "_Solved":
        n = len(samples)
        return cls(samples, np.full((n, n_effectors, 3), np.nan), np.zeros(n, bool), np.zeros(n, int),
                   np.zeros(n, bool), np.zeros(n, bool),
                   [{"sample": int(i), "error": type(error).__name__, "message": str(error)} for i in samples], 0.0,
                   np.zeros(n, bool), np.zeros(n, bool))


class _Equilibrium:
    """A solved sample that later samples start from, with the tangent of the equilibrium path
    through it, ``dq/dλ = K⁻¹ B`` (computed when first asked for)."""

    def __init__(self, model, state, actuation):
        self.model, self.state, self.actuation = model, state, actuation
        self._path = None

    def start_for(self, actuation: np.ndarray):
        """Euler predictor: the state moved along the path tangent by the change of actuation
        (the plain equilibrium where the tangent cannot be factored)."""
        if self._path is None:
            try:
                lin = self.model.linearise(self.state, self.actuation)
                self._path = lin.solve(lin.actuator_forces)
            except SOLVE_FAILURES:
                self._path = False
        if self._path is False:
            return self.state, False
        return self.model.step(self.state, self._path @ (actuation - self.actuation)), True


def _solve_samples(model, actuations: np.ndarray, order: np.ndarray, parent: np.ndarray,
                   tolerance: float | None, progress=None) -> _Solved:
    """Solve ``actuations[i]`` for ``i`` in ``order``, each from the Euler prediction off its
    parent's equilibrium when the parent is among them (else from rest). ``actuations`` and
    ``parent`` are indexed by sample; equilibria are kept only while a later sample still
    starts from them."""
    cpu = time.process_time()
    n = len(order)
    positions = np.full((n, len(model.effector_names), 3), np.nan)
    converged, warm, predicted = np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, bool)
    iterations = np.zeros(n, int)
    beyond, outside = np.zeros(n, bool), np.zeros(n, bool)
    violations: dict = {}
    failures = []
    inside = set(order.tolist())
    parents = [p if p in inside else -1 for p in parent[order].tolist()]
    children = {}
    for p in parents:
        if p >= 0:
            children[p] = children.get(p, 0) + 1
    kept = {}
    for j, (i, p) in enumerate(zip(order.tolist(), parents)):
        initial = None
        if p in kept:
            initial, predicted[j] = kept[p].start_for(actuations[i])
        warm[j] = initial is not None
        try:
            result = model.solve(actuations[i], initial=initial, tolerance=tolerance)
        except SOLVE_FAILURES as error:
            iterations[j] = getattr(getattr(error, "result", None), "iterations", 0)
            failures.append({"sample": i, "error": type(error).__name__, "message": str(error)})
        else:
            converged[j] = True
            iterations[j] = result.iterations
            positions[j] = model.effector_positions(result.state)
            beyond[j], outside[j] = bool(result.bound_violations), bool(result.out_of_range)
            for key in {f"{v.actuator}: {v.bound}" for v in result.bound_violations} | \
                    {f"{e.source}: {e.quantity}" for e in result.out_of_range}:
                violations[key] = violations.get(key, 0) + 1
            if children.get(i):
                kept[i] = _Equilibrium(model, result.state, actuations[i])
        if p >= 0:
            children[p] -= 1
            if not children[p]:
                kept.pop(p, None)
        if progress is not None:
            progress(1)
    return _Solved(order, positions, converged, iterations, warm, predicted, failures,
                   time.process_time() - cpu, beyond, outside, violations)


_WORKER_MODEL = None


def _start_worker(model) -> None:
    global _WORKER_MODEL
    _WORKER_MODEL = model


def _solve_in_worker(actuations, order, parent, tolerance) -> _Solved:
    return _solve_samples(_WORKER_MODEL, actuations, order, parent, tolerance)


def _children_cpu_s() -> float:
    """CPU seconds of this process's finished child processes (0 where not measurable)."""
    try:
        import resource
    except ImportError:
        return 0.0
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _solve_in_workers(model, actuations, plan: SolveOrder, tolerance, workers: int, chunk: int,
                      progress) -> list:
    """The solve order cut into runs of ``chunk`` samples, solved by ``workers`` processes
    (started with ``spawn``; each receives the model once). A run's first sample, and any whose
    parent is in another run, starts from rest."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    runs = [plan.order[k:k + chunk] for k in range(0, len(plan.order), chunk)]
    solved = []
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                             initializer=_start_worker, initargs=(model,)) as pool:
        futures = {pool.submit(_solve_in_worker, actuations, run, plan.parent, tolerance): run for run in runs}
        for future in as_completed(futures):
            run = futures[future]
            try:
                solved.append(future.result())
            except Exception as error:     # the worker process itself failed: its samples failed
                solved.append(_Solved.failed(run, len(model.effector_names), error))
            if progress is not None:
                progress(len(run))
    return solved


def sample_workspace(model, n_samples: int = 1000, *, method: str = "sobol", seed: int = 0,
                     ordering: str = "tree", tolerance: float | None = None, workers: int = 1,
                     chunk: int = CHUNK, actuations: np.ndarray | None = None,
                     progress: Callable[[int], object] | None = None, drop_outside: bool = False) -> Workspace:
    """Solve the trunk at ``n_samples`` quasi-random actuations within the bounds (or at the
    given ``actuations``) and collect the effector positions.

    Each sample starts from the Euler prediction off the equilibrium of the sample
    ``ordering`` names as its parent (:data:`ORDERINGS`); the solver itself falls back to load
    stepping from rest when such a warm start fails. ``tolerance`` overrides the scene's Newton
    tolerance. ``workers`` > 1 solves runs of ``chunk`` consecutive samples of the order in
    that many processes. ``progress(k)`` is called as ``k`` more samples are done (e.g. a tqdm
    bar's ``update``). Samples whose equilibrium breaks a bound of the scene the box does not
    hold (strokes, volume growths, tendon tensions) or leaves a fitted range are counted and
    flagged; ``drop_outside`` leaves them out of the clouds."""
    if ordering not in ORDERINGS:
        raise OptionError(f"unknown ordering {ordering!r}; choose one of {', '.join(ORDERINGS)}",
                          field="ordering")
    if tolerance is not None and not (tolerance > 0 and math.isfinite(tolerance)):
        raise OptionError(f"must be a positive number, got {tolerance}", field="tolerance")
    for name, value in (("workers", workers), ("chunk", chunk)):
        if not (isinstance(value, int) and value >= 1):
            raise OptionError(f"must be a positive whole number, got {value}", field=name)
    wall, cpu, children_cpu = time.perf_counter(), time.process_time(), _children_cpu_s()
    sampled = actuations is None
    if sampled:
        actuations = sample_actuations(model, n_samples, method=method, seed=seed)
    else:
        actuations = np.array(actuations, float, ndmin=2)
        if actuations.shape[1:] != (len(model.actuator_names),):
            raise OptionError(f"actuations must be (n, {len(model.actuator_names)}), got {actuations.shape}",
                              field="actuations")
    n = len(actuations)
    plan = ORDERINGS[ordering](response_coordinates(model, actuations))
    order_s = time.perf_counter() - wall
    if workers == 1 or n <= chunk:
        pieces = [_solve_samples(model, actuations, plan.order, plan.parent, tolerance, progress)]
    else:
        pieces = _solve_in_workers(model, actuations, plan, tolerance, workers, chunk, progress)

    per_sample = {"positions": np.full((n, len(model.effector_names), 3), np.nan),
                  "converged": np.zeros(n, bool), "iterations": np.zeros(n, int),
                  "warm": np.zeros(n, bool), "predicted": np.zeros(n, bool),
                  "beyond_bounds": np.zeros(n, bool), "out_of_range": np.zeros(n, bool)}
    violations: dict = {}
    for piece in pieces:
        for name, values in per_sample.items():
            values[piece.samples] = getattr(piece, name)
        for key, count in piece.violations.items():
            violations[key] = violations.get(key, 0) + count
    failures = sorted((f for piece in pieces for f in piece.failures), key=lambda f: f["sample"])
    settings = {"samples": n, "method": method if sampled else "given", "seed": seed, "ordering": ordering,
                "tolerance": model.scene.solver.tolerance if tolerance is None else tolerance,
                "workers": workers, "drop_outside": bool(drop_outside)}
    timings = {"order_s": order_s, "wall_s": time.perf_counter() - wall,
               "cpu_s": time.process_time() - cpu + _children_cpu_s() - children_cpu,
               "solve_cpu_s": float(sum(piece.cpu_s for piece in pieces))}
    return Workspace(list(model.actuator_names), list(model.effector_names),
                     np.asarray(model.effector_is_axis, bool).copy(),
                     tuple(np.array(b, float) for b in model.actuator_bounds), actuations, **per_sample,
                     failures=failures, order=plan, settings=settings, timings=timings,
                     violations=dict(sorted(violations.items())), drop_outside=bool(drop_outside))


# ---------------------------------------------------------------------------- files
def write_points(workspace: Workspace, path) -> None:
    """Every sample as a row: actuations, then ``<effector>.x/.y/.z``, ``converged``,
    ``iterations``, ``beyond_bounds`` and ``out_of_range`` (1/0; ``.csv``), or the same arrays in
    a ``.npz``."""
    from pathlib import Path

    path = Path(path)
    if path.suffix == ".npz":
        np.savez_compressed(path, actuations=workspace.actuations, positions=workspace.positions,
                            converged=workspace.converged, iterations=workspace.iterations,
                            beyond_bounds=workspace.beyond_bounds, out_of_range=workspace.out_of_range,
                            actuator_names=np.array(workspace.actuator_names),
                            effector_names=np.array(workspace.effector_names))
        return
    if path.suffix != ".csv":
        raise OptionError(f"{path}: points are written as .csv or .npz", field="--points")
    header = list(workspace.actuator_names)
    header += [f"{name}.{axis}" for name in workspace.effector_names for axis in "xyz"]
    header += ["converged", "iterations", "beyond_bounds", "out_of_range"]
    table = np.column_stack([workspace.actuations, workspace.positions.reshape(workspace.n_samples, -1),
                             workspace.converged.astype(float), workspace.iterations.astype(float),
                             workspace.beyond_bounds.astype(float), workspace.out_of_range.astype(float)])
    np.savetxt(path, table, delimiter=",", header=",".join(header), comments="", fmt="%.17g")
