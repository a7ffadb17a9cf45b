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

    * ``"levels"`` (default): coarse to fine for solving in batches — every 512th sample from
      rest, every other 64th from the nearest of those, every other 8th from the nearest of all
      these, the others from the nearest of all (up to four generations, each one batch).
    * ``"tree"``: the minimum spanning tree of the k-nearest-neighbour graph in that
      response space, visited depth first from the least deformed sample; each sample starts
      from its tree parent. Every warm start is a shortest available edge, and a parent with
      several children serves them all (but the tree is ~150 generations deep).
    * ``"chain"``: a greedy nearest-neighbour chain in the same space (each sample starts from
      the previous one); its last links are long jumps between leftover samples.
    * ``"sampled"``: the order the sequence drew them in (neighbours are far apart).

Warm start
    A sample does not start from its parent's equilibrium ``ξ_p`` itself but from a
    second-order predictor along the equilibrium path, ``ξ_p + ξ'_p Δλ + ½ ξ''_p[Δλ, Δλ]``
    (:func:`predicted_starts`): the path tangent ``ξ' = dξ/dλ`` of the parent's equilibrium
    (factored once per parent), the curvature from the path tangents of the parent's solved
    neighbours. Newton's own first step from ``ξ_p`` uses the tangent at the new load, which is
    not the path's derivative, and needs about four more iterations on the paper's 16-tendon
    robot; the Euler predictor alone about half an iteration more per sample.

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

from vertebra.solver.batch import kept_heap, strain_paths
from vertebra.solver.hull import Hull, convex_hull
from vertebra.solver.workspace_order import ORDERINGS, SolveOrder, generations, response_coordinates
from vertebra.core.lie import qrotate
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
CHUNK = 4096             # samples of one generation solved together (per worker task)


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


def _solve_part(model, actuations: np.ndarray, start: np.ndarray, tolerance: float | None) -> dict:
    """One batch of samples (:meth:`TrunkModel.solve_batch`, ``start``: link strains, nan rows from
    rest): what the workspace keeps of each, the equilibria's link strains included."""
    cpu = time.process_time()
    result = model.solve_batch(actuations, start, tolerance=tolerance)
    trunk = model.trunk
    effectors = trunk.effectors
    f = effectors.frames
    positions = np.full((len(actuations), len(effectors.names), 3), np.nan)
    ok = result.converged
    if ok.any():
        turned = qrotate(result.quaternions[ok][:, f], effectors.offsets)
        positions[ok] = result.positions[ok][:, f] * effectors.point_mask + turned
    violations = [sorted({f"{v.actuator}: {v.bound}" for v in result.bound_violations[i]}
                         | {f"{e.source}: {e.quantity}" for e in result.out_of_range[i]}) for i in range(len(ok))]
    return {"converged": ok, "iterations": result.iterations, "strains": result.strains, "positions": positions,
            "messages": result.messages, "errors": result.errors, "violations": violations,
            "beyond": np.array([bool(v) for v in result.bound_violations], bool) & ok,
            "outside": np.array([bool(v) for v in result.out_of_range], bool) & ok,
            "cpu_s": time.process_time() - cpu}


_WORKER_MODEL = None


def _start_worker(model) -> None:
    global _WORKER_MODEL
    _WORKER_MODEL = model


def _solve_in_worker(actuations, start, tolerance) -> dict:
    return _solve_part(_WORKER_MODEL, actuations, start, tolerance)


def _children_cpu_s() -> float:
    """CPU seconds of this process's finished child processes (0 where not measurable)."""
    try:
        import resource
    except ImportError:
        return 0.0
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


class _InProcess:
    """Parts solved one after the other in this process."""

    def __init__(self, model):
        self.model = model

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        return None

    workers = 1

    def map(self, parts, tolerance):
        for part in parts:
            yield part, _solve_part(self.model, part[1], part[2], tolerance)


class _Processes:
    """Parts solved by ``workers`` processes (spawned, one BLAS thread each; each receives the
    compiled model once)."""

    def __init__(self, model, workers: int):
        self.model, self.workers = model, workers
        self._pool = None

    def __enter__(self):
        import multiprocessing
        import os
        from concurrent.futures import ProcessPoolExecutor

        for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ.setdefault(name, "1")      # (inherited by the spawned workers)
        self._pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=multiprocessing.get_context("spawn"),
                                         initializer=_start_worker, initargs=(self.model,))
        return self

    def __exit__(self, *exc_info):
        self._pool.shutdown()
        return None

    def map(self, parts, tolerance):
        from concurrent.futures import as_completed

        futures = {self._pool.submit(_solve_in_worker, part[1], part[2], tolerance): part for part in parts}
        for future in as_completed(futures):
            part = futures[future]
            try:
                yield part, future.result()
            except Exception as error:     # the worker process itself failed: its samples failed
                yield part, error


class _Dask:
    """Parts solved on a dask cluster: the one at ``scheduler``, or a LocalCluster of ``workers``
    single-threaded worker processes (dask's nannies start them with one BLAS thread)."""

    def __init__(self, model, workers: int, scheduler: str | None):
        self.model, self.workers, self.scheduler = model, workers, scheduler
        self._client = self._cluster = self._model = None

    def __enter__(self):
        import logging

        from dask.distributed import Client, LocalCluster

        if self.scheduler:
            try:
                self._client = Client(self.scheduler, timeout="20s")
            except (OSError, TimeoutError) as error:
                raise OptionError(f"cannot reach dask scheduler {self.scheduler!r}: {error}",
                                  field="scheduler") from None
        else:
            self._cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                         dashboard_address=None, silence_logs=logging.ERROR)
            self._client = Client(self._cluster)
        self._model = self._client.scatter(self.model, broadcast=True)
        return self

    def __exit__(self, *exc_info):
        self._client.close()
        if self._cluster is not None:
            self._cluster.close()
        return None

    def map(self, parts, tolerance):
        from dask.distributed import as_completed

        futures = {self._client.submit(_solve_part, self._model, part[1], part[2], tolerance, pure=False): part
                   for part in parts}
        for future in as_completed(list(futures)):
            part = futures.pop(future)
            try:
                yield part, future.result()
            except Exception as error:  # noqa: BLE001 - a worker that died, a result that did not arrive
                yield part, error
            future.release()


EXECUTORS = ("local", "dask")

SECANT_NEIGHBOURS = 32   # solved neighbours whose path tangents estimate a parent's second derivative
SECANT_RIDGE = 1e-3      # ridge on the neighbours' weights, relative to their mean squared distance


def predicted_starts(strains: np.ndarray, paths: np.ndarray, has: np.ndarray, actuations: np.ndarray,
                     coordinates: np.ndarray, scale: np.ndarray, of: np.ndarray, change: np.ndarray) -> np.ndarray:
    """Start strains (m, n, 6) of m children from their parents' equilibria: the second-order
    predictor ``ξ_p + ξ'_p Δ + ½ ξ''_p[Δ, Δ]`` along the equilibrium path (the Euler predictor
    ``ξ_p + ξ'_p Δ`` plus its curvature term).

    ``strains`` (P, n, 6) the parents' equilibria, ``paths`` (P, n, 6, a) their strain path
    tangents ``ξ' = dξ/dλ`` (:func:`vertebra.solver.batch.strain_paths`), ``has`` (P,) which have
    one, ``actuations`` (P, a), ``coordinates`` (P, r) their response coordinates (nearness),
    ``scale`` (a,) the actuators' ranges; ``of`` (m,) each child's parent, ``change`` (m, a) its
    actuation minus its parent's.

    The curvature term comes from the path tangents of the parent's nearest solved neighbours
    ``j`` (secants of the tangent field): ``ξ'_j − ξ'_p ≈ ξ''_p[d_j, ·]`` with ``d_j = λ_j − λ_p``,
    so writing ``Δ ≈ Σ c_j d_j`` (ridge least squares in the actuation box's units) gives
    ``ξ''_p[Δ, ·] ≈ Σ c_j (ξ'_j − ξ'_p)``. A child whose curvature term comes out larger than its
    Euler step (the expansion not to be trusted there) keeps the Euler predictor."""
    start = strains[of].copy()
    move = np.flatnonzero(has[of])
    if not move.size:
        return start
    users, slot = np.unique(of[move], return_inverse=True)
    children = move[np.argsort(slot, kind="stable")]                 # the children, parent by parent
    bounds = np.searchsorted(np.sort(slot), np.arange(users.size + 1))
    valid = np.flatnonzero(has)
    k = min(SECANT_NEIGHBOURS, valid.size - 1)
    if k >= 2:
        from scipy.spatial import cKDTree

        _, near = cKDTree(coordinates[valid]).query(coordinates[users], k=k + 1)
        near = valid[near]
        other = near != users[:, None]                                # leave the parent itself out
        near = np.take_along_axis(near, np.argsort(~other, axis=1, kind="stable")[:, :k], 1)
        d = (actuations[near] - actuations[users][:, None]) / scale          # (U, k, a) in box units
        gram = d.mT @ d
        ridge = np.maximum(SECANT_RIDGE * np.trace(gram, axis1=1, axis2=2) / k, np.finfo(float).tiny)
        gram[:, np.arange(scale.size), np.arange(scale.size)] += ridge[:, None]   # (neighbours all at λ_p: c = 0)
        weights = d @ np.linalg.inv(gram)                                    # (U, k, a): c = W (Δ / scale)
    flat = paths.reshape(paths.shape[0], -1)
    shape = paths.shape[1:]
    for u, p in enumerate(users.tolist()):
        rows = children[bounds[u]:bounds[u + 1]]
        delta = change[rows]
        step = (paths[p] @ delta.T[None]).transpose(2, 0, 1)                 # (c, n, 6) Euler
        start[rows] += step
        if k < 2:
            continue
        c = (delta / scale) @ weights[u].T                                     # (c, k)
        second = (c @ (flat[near[u]] - flat[p])).reshape((rows.size,) + shape)
        curvature = 0.5 * (second @ delta[:, None, :, None])[..., 0]
        trusted = (np.max(np.abs(curvature).reshape(rows.size, -1), 1)
                   <= np.max(np.abs(step).reshape(rows.size, -1), 1))
        start[rows[trusted]] += curvature[trusted]
    return start


def _solve_generations(model, actuations: np.ndarray, plan: SolveOrder, coordinates: np.ndarray, tolerance,
                       executor, chunk: int, progress) -> _Solved:
    """Solve the samples generation by generation (:func:`generations`): each generation in
    batches (parts of at most ``chunk`` samples, spread over the executor's workers), every
    sample from the second-order prediction off its parent's equilibrium
    (:func:`predicted_starts`; the path tangents of a generation's parents computed together),
    from rest where it has none."""
    n = len(actuations)
    n_links = model.trunk.links.count
    depth = generations(plan)
    scale = np.ptp(actuations, 0)
    scale = np.where(scale > 0.0, scale, 1.0)              # the actuators' spread (units of the secants)
    positions = np.full((n, len(model.effector_names), 3), np.nan)
    converged, warm, predicted = np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, bool)
    iterations = np.zeros(n, int)
    beyond, outside = np.zeros(n, bool), np.zeros(n, bool)
    violations: dict = {}
    failures = []
    cpu = 0.0
    parents = plan.parent
    last_use = np.full(n, -1)                   # the last generation that starts from a sample
    child = parents >= 0
    np.maximum.at(last_use, parents[child], depth[child])
    kept = {}                                   # link strains of solved samples that later ones start from
    rank = np.empty(n, int)
    rank[plan.order] = np.arange(n)
    for generation in range(int(depth.max(initial=0)) + 1):
        wave = np.flatnonzero(depth == generation)
        wave = wave[np.argsort(rank[wave], kind="stable")]
        start = np.full((wave.size, n_links, 6), np.nan)
        mine = parents[wave]
        from_parent = np.flatnonzero((mine >= 0) & converged[np.maximum(mine, 0)])
        if from_parent.size:
            up = np.unique(mine[from_parent])
            strains = np.stack([kept[p] for p in up.tolist()])
            paths, has = strain_paths(model, strains, actuations[up])       # dξ/dλ of every parent
            which = np.searchsorted(up, mine[from_parent])
            move = has[which]
            start[from_parent] = predicted_starts(strains, paths, has, actuations[up], coordinates[up], scale,
                                                  which, actuations[wave[from_parent]] - actuations[mine[from_parent]])
            warm[wave[from_parent]] = True
            predicted[wave[from_parent[move]]] = True
        size = max(1, min(chunk, -(-wave.size // max(1, executor.workers))))
        parts = [(wave[k:k + size], actuations[wave[k:k + size]], start[k:k + size])
                 for k in range(0, wave.size, size)]
        for (rows, _, _), found in executor.map(parts, tolerance):
            if isinstance(found, BaseException):
                for i in rows.tolist():
                    failures.append({"sample": i, "error": type(found).__name__, "message": str(found)})
                if progress is not None:
                    progress(len(rows))
                continue
            cpu += found["cpu_s"]
            ok = found["converged"]
            converged[rows], iterations[rows] = ok, found["iterations"]
            positions[rows] = found["positions"]
            beyond[rows], outside[rows] = found["beyond"], found["outside"]
            for j, i in enumerate(rows.tolist()):
                if ok[j]:
                    for key in found["violations"][j]:
                        violations[key] = violations.get(key, 0) + 1
                    if last_use[i] > generation:
                        kept[i] = found["strains"][j]
                else:
                    failures.append({"sample": i, "error": found["errors"][j] or "ConvergenceError",
                                     "message": found["messages"][j]})
            if progress is not None:
                progress(len(rows))
        for p in [p for p in kept if last_use[p] <= generation]:    # no later generation starts from them
            del kept[p]
    return _Solved(plan.order, positions[plan.order], converged[plan.order], iterations[plan.order],
                   warm[plan.order], predicted[plan.order], failures, cpu, beyond[plan.order], outside[plan.order],
                   violations)


def sample_workspace(model, n_samples: int = 1000, *, method: str = "sobol", seed: int = 0,
                     ordering: str = "levels", tolerance: float | None = None, workers: int = 1,
                     chunk: int = CHUNK, actuations: np.ndarray | None = None,
                     progress: Callable[[int], object] | None = None, drop_outside: bool = False,
                     executor: str = "local", scheduler: str | None = None) -> Workspace:
    """Solve the trunk at ``n_samples`` quasi-random actuations within the bounds (or at the
    given ``actuations``) and collect the effector positions.

    The samples are solved in batches (:meth:`TrunkModel.solve_batch`), generation by
    generation of ``ordering`` (:data:`ORDERINGS`): each sample starts from the Euler prediction
    off the equilibrium of the sample the ordering names as its parent (solved in an earlier
    generation); the solver itself falls back to load stepping from rest when such a warm start
    fails. ``tolerance`` overrides the scene's Newton tolerance. A generation is cut into parts
    of at most ``chunk`` samples spread over ``workers`` processes (``executor="local"``), or
    over a dask cluster (``executor="dask"``: the one at ``scheduler``, or a LocalCluster of
    ``workers`` processes). ``progress(k)`` is called as ``k`` more samples are done (e.g. a
    tqdm bar's ``update``). Samples whose equilibrium breaks a bound of the scene the box does
    not hold (strokes, volume growths, tendon tensions) or leaves a fitted range are counted and
    flagged; ``drop_outside`` leaves them out of the clouds."""
    if ordering not in ORDERINGS:
        raise OptionError(f"unknown ordering {ordering!r}; choose one of {', '.join(ORDERINGS)}",
                          field="ordering")
    if executor not in EXECUTORS:
        raise OptionError(f"unknown executor {executor!r}; choose one of {', '.join(EXECUTORS)}", field="executor")
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
    coordinates = response_coordinates(model, actuations)
    plan = ORDERINGS[ordering](coordinates)
    order_s = time.perf_counter() - wall
    if executor == "dask":
        pool = _Dask(model, workers, scheduler)
    elif workers > 1 and n > chunk:
        pool = _Processes(model, workers)
    else:
        pool = _InProcess(model)
    with pool, kept_heap():
        pieces = [_solve_generations(model, actuations, plan, coordinates, tolerance, pool, chunk, progress)]

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
                "workers": workers, "executor": executor, "drop_outside": bool(drop_outside)}
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
