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

from vertebra.store.errors import ConvergenceError, OptionError, SceneError

SAMPLERS = ("sobol", "halton")
NEIGHBOURS = 10          # k of the nearest-neighbour graph the spanning tree is taken from
RESPONSE_RANK = 1e-6     # response directions below this fraction of the largest are dropped

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
            name, table, which = model.actuator_names[k], f"cable[{k}]", "tension"
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
    if n_samples < 1:
        raise OptionError(f"need at least one sample, got {n_samples}", field="samples")
    if method == "halton":
        return qmc.Halton(dimension, seed=seed).random(n_samples)
    # a prefix of a scrambled Sobol sequence is still low-discrepancy; only its balance
    # properties need a power of two, which is what scipy warns about
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return qmc.Sobol(dimension, seed=seed).random(n_samples)


def sample_actuations(model, n_samples: int, *, method: str = "sobol", seed: int = 0) -> np.ndarray:
    """``(n_samples, n_actuators)`` actuations inside the bounds (tensions N, pressures Pa)."""
    lower, upper = actuation_box(model)
    return lower + sample_unit(n_samples, lower.size, method=method, seed=seed) * (upper - lower)


# ---------------------------------------------------------------------------- solve order
def response_coordinates(model, actuations: np.ndarray) -> np.ndarray:
    """Coordinates of each actuation in the trunk's linear response at rest, ``K⁻¹ B λ``
    (translations m, rotations × trunk length), on its principal directions: Euclidean
    distances there approximate how far apart two samples' equilibria are."""
    actuations = np.asarray(actuations, float)
    lower = np.asarray(model.actuator_bounds[0], float)
    lower = np.where(np.isfinite(lower), lower, 0.0)         # given actuations need no finite box
    lin = model.linearise(model.rest_state, lower)
    response = lin.solve(lin.actuator_forces)                         # (n_dof, n_act)
    response = response.reshape(-1, 6, response.shape[1])
    response[:, 3:] *= model.length_scale
    _, s, vt = np.linalg.svd(response.reshape(-1, response.shape[2]), full_matrices=False)
    keep = s > RESPONSE_RANK * s[0] if s.size and s[0] > 0 else np.zeros(s.size, bool)
    if not np.any(keep):
        return np.zeros((len(actuations), 1))
    return (actuations - lower) @ (vt[keep].T * s[keep])


@dataclass(frozen=True)
class SolveOrder:
    """The order to solve the samples in, and whose equilibrium each one starts from
    (``parent[i] = -1``: from rest)."""

    order: np.ndarray
    parent: np.ndarray

    def __post_init__(self):
        n = self.parent.size
        if self.order.shape != (n,) or not np.array_equal(np.sort(self.order), np.arange(n)):
            raise ValueError("order must be a permutation of the samples")
        position = np.empty(n, int)
        position[self.order] = np.arange(n)
        has = self.parent >= 0
        if np.any(position[self.parent[has]] >= position[has]):
            raise ValueError("every sample's parent must be solved before it")


def _squared_norms(coordinates: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", coordinates, coordinates)


def order_sampled(coordinates: np.ndarray) -> SolveOrder:
    """The order the sequence drew the samples in, each from the previous one."""
    n = len(coordinates)
    return SolveOrder(np.arange(n), np.arange(n) - 1)


def order_chain(coordinates: np.ndarray) -> SolveOrder:
    """Greedy nearest-neighbour chain from the least deformed sample (k-d tree queries
    widened until an unvisited neighbour appears)."""
    from scipy.spatial import cKDTree

    n = len(coordinates)
    tree = cKDTree(coordinates)
    visited = np.zeros(n, bool)
    order = np.empty(n, int)
    current = int(np.argmin(_squared_norms(coordinates)))
    for i in range(n):
        order[i] = current
        visited[current] = True
        if i == n - 1:
            break
        k = NEIGHBOURS
        while True:
            _, near = tree.query(coordinates[current], k=min(k, n))
            near = np.atleast_1d(near)
            free = near[~visited[near]]
            if free.size:
                current = int(free[0])
                break
            k *= 4        # k ≥ n returns every sample, unvisited ones included
    parent = np.empty(n, int)
    parent[order[0]] = -1
    parent[order[1:]] = order[:-1]
    return SolveOrder(order, parent)


def order_tree(coordinates: np.ndarray) -> SolveOrder:
    """Depth-first visit of the minimum spanning tree of the k-nearest-neighbour graph from
    the least deformed sample; each sample's parent is its tree neighbour on the way from
    that root. Pieces the graph leaves disconnected start from rest."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components, depth_first_order, minimum_spanning_tree
    from scipy.spatial import cKDTree

    n = len(coordinates)
    if n == 1:
        return SolveOrder(np.zeros(1, int), np.full(1, -1))
    k = min(NEIGHBOURS, n - 1)
    distance, near = cKDTree(coordinates).query(coordinates, k=k + 1)
    rows = np.repeat(np.arange(n), k)
    # coincident samples are still neighbours: a zero weight would read as "no edge"
    weights = np.maximum(distance[:, 1:].ravel(), np.finfo(float).tiny)
    graph = coo_matrix((weights, (rows, near[:, 1:].ravel())), shape=(n, n)).tocsr()
    tree = minimum_spanning_tree(graph.maximum(graph.T))
    tree = tree.maximum(tree.T)
    _, label = connected_components(tree, directed=False)
    squared = _squared_norms(coordinates)
    order, parent = [], np.full(n, -1)
    for component in np.unique(label):
        members = np.flatnonzero(label == component)
        root = int(members[np.argmin(squared[members])])
        visit, predecessor = depth_first_order(tree, root, directed=False)
        order.append(visit)
        parent[visit[1:]] = predecessor[visit[1:]]
    return SolveOrder(np.concatenate(order), parent)


ORDERINGS: dict[str, Callable[[np.ndarray], SolveOrder]] = {
    "tree": order_tree,
    "chain": order_chain,
    "sampled": order_sampled,
}


# ---------------------------------------------------------------------------- results
@dataclass(frozen=True)
class Hull:
    """Convex hull of a point cloud in its affine span: ``dimension`` 3 gives ``volume`` (m³)
    and ``area`` (surface, m²); 2 (a planar cloud) gives ``area`` (m²) and no volume; 1 or 0
    neither. ``simplices`` index the cloud's points (triangles in 3D, edges in 2D)."""

    dimension: int
    volume: float | None
    area: float | None
    simplices: np.ndarray
    vertices: np.ndarray


def affine_dimension(points: np.ndarray, *, tolerance: float = 1e-9) -> int:
    """Dimension of the affine span of ``points``: singular values of the centred cloud above
    ``tolerance`` × its extent × √(number of points) count."""
    if len(points) < 2:
        return 0
    centred = points - points.mean(0)
    s = np.linalg.svd(centred, compute_uv=False)
    scale = max(float(np.ptp(points, axis=0).max()), np.finfo(float).tiny)
    return int(np.sum(s > tolerance * scale * math.sqrt(len(points))))


def convex_hull(points: np.ndarray) -> Hull:
    """Convex hull of a 3D point cloud; of a planar cloud, taken in its plane."""
    from scipy.spatial import ConvexHull, QhullError

    points = np.asarray(points, float)
    dimension = affine_dimension(points)
    if dimension == 3:
        try:
            hull = ConvexHull(points)
            return Hull(3, float(hull.volume), float(hull.area), hull.simplices, hull.vertices)
        except QhullError:        # nearly flat beyond what the rank test caught
            dimension = 2
    if dimension == 2:
        centred = points - points.mean(0)
        basis = np.linalg.svd(centred, full_matrices=False)[2][:2]
        try:
            hull = ConvexHull(centred @ basis.T)
            return Hull(2, None, float(hull.volume), hull.simplices, hull.vertices)   # 2D: volume = area
        except QhullError:
            dimension = 1
    return Hull(dimension, None, None, np.zeros((0, 3), int), np.zeros(0, int))


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
    where sample ``i``'s solve failed; ``failures`` lists those samples with the error."""

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

    def __post_init__(self):
        n = len(self.actuations)
        shapes = {"positions": (n, len(self.effector_names), 3), "converged": (n,), "iterations": (n,),
                  "warm": (n,), "predicted": (n,)}
        for name, shape in shapes.items():
            if getattr(self, name).shape != shape:
                raise ValueError(f"{name} has shape {getattr(self, name).shape}, expected {shape}")

    @property
    def n_samples(self) -> int:
        return len(self.actuations)

    def cloud(self, name: str) -> EffectorCloud:
        """The converged positions of effector ``name``."""
        k = self.effector_names.index(name)
        return EffectorCloud(name, "direction" if self.effector_is_axis[k] else "point",
                             self.positions[self.converged, k])

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

    @classmethod
    def failed(cls, samples: np.ndarray, n_effectors: int, error: BaseException) -> "_Solved":
        n = len(samples)
        return cls(samples, np.full((n, n_effectors, 3), np.nan), np.zeros(n, bool), np.zeros(n, int),
                   np.zeros(n, bool), np.zeros(n, bool),
                   [{"sample": int(i), "error": type(error).__name__, "message": str(error)} for i in samples], 0.0)


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
            if children.get(i):
                kept[i] = _Equilibrium(model, result.state, actuations[i])
        if p >= 0:
            children[p] -= 1
            if not children[p]:
                kept.pop(p, None)
        if progress is not None:
            progress(1)
    return _Solved(order, positions, converged, iterations, warm, predicted, failures,
                   time.process_time() - cpu)


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
                     progress: Callable[[int], object] | None = None) -> Workspace:
    """Solve the trunk at ``n_samples`` quasi-random actuations within the bounds (or at the
    given ``actuations``) and collect the effector positions.

    Each sample starts from the Euler prediction off the equilibrium of the sample
    ``ordering`` names as its parent (:data:`ORDERINGS`); the solver itself falls back to load
    stepping from rest when such a warm start fails. ``tolerance`` overrides the scene's Newton
    tolerance. ``workers`` > 1 solves runs of ``chunk`` consecutive samples of the order in
    that many processes. ``progress(k)`` is called as ``k`` more samples are done (e.g. a tqdm
    bar's ``update``)."""
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
                  "warm": np.zeros(n, bool), "predicted": np.zeros(n, bool)}
    for piece in pieces:
        for name, values in per_sample.items():
            values[piece.samples] = getattr(piece, name)
    failures = sorted((f for piece in pieces for f in piece.failures), key=lambda f: f["sample"])
    settings = {"samples": n, "method": method if sampled else "given", "seed": seed, "ordering": ordering,
                "tolerance": model.scene.solver.tolerance if tolerance is None else tolerance,
                "workers": workers}
    timings = {"order_s": order_s, "wall_s": time.perf_counter() - wall,
               "cpu_s": time.process_time() - cpu + _children_cpu_s() - children_cpu,
               "solve_cpu_s": float(sum(piece.cpu_s for piece in pieces))}
    return Workspace(list(model.actuator_names), list(model.effector_names),
                     np.asarray(model.effector_is_axis, bool).copy(),
                     tuple(np.array(b, float) for b in model.actuator_bounds), actuations, **per_sample,
                     failures=failures, order=plan, settings=settings, timings=timings)


# ---------------------------------------------------------------------------- files
def write_points(workspace: Workspace, path) -> None:
    """Every sample as a row: actuations, then ``<effector>.x/.y/.z``, ``converged`` and
    ``iterations`` (``.csv``), or the same arrays in a ``.npz``."""
    from pathlib import Path

    path = Path(path)
    if path.suffix == ".npz":
        np.savez_compressed(path, actuations=workspace.actuations, positions=workspace.positions,
                            converged=workspace.converged, iterations=workspace.iterations,
                            actuator_names=np.array(workspace.actuator_names),
                            effector_names=np.array(workspace.effector_names))
        return
    if path.suffix != ".csv":
        raise OptionError(f"{path}: points are written as .csv or .npz", field="--points")
    header = list(workspace.actuator_names)
    header += [f"{name}.{axis}" for name in workspace.effector_names for axis in "xyz"]
    header += ["converged", "iterations"]
    table = np.column_stack([workspace.actuations, workspace.positions.reshape(workspace.n_samples, -1),
                             workspace.converged.astype(float), workspace.iterations.astype(float)])
    np.savetxt(path, table, delimiter=",", header=",".join(header), comments="", fmt="%.17g")
