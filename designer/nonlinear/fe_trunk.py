"""Full geometrically nonlinear FE reference of a trunk: segments joined by rigid vertebrae.

Vertebra 0 is clamped at the base pose; vertebrae 1..m are rigid bodies with
6 DoFs each (position of the origin, rotation updated by the exponential map,
``t ← t + v``, ``R ← exp(ω̂) R``, ``v`` and ``ω`` in world axes). Segment ``s``
(a :class:`~.segment.NonlinearSegment`; the same one may be repeated) lies between
vertebrae ``s`` and ``s + 1``: the nodes of its bottom face are tied exactly to
vertebra ``s`` and those of its top face to vertebra ``s + 1``
(``x = t_k + R_k (X − c)``, :mod:`.framed`). At rest the trunk is straight along the
base frame's +z, vertebra ``k`` at the sum of the lengths below it.

Loads (world frame), all scaled together by the load factor during load stepping:

* dead forces at vertebra origins and dead moments on vertebrae (a dead moment is
  not conservative in 3-D: the tangent includes the skew part ``−½ m̂`` of the
  exponential-map parametrisation, ``m`` the moment of the conservative forces on
  the vertebra, and the linear system is solved by LU);
* gravity: the segments' own weight (body force ρ g) and vertebra masses at their
  centres of mass (in the vertebra frame);
* cavity pressures per segment (follower loads on the walls and the caps carried
  by the vertebrae, exactly as in the segment model).

Newton on the whole system, solved by static condensation of each segment's
interior onto its two vertebrae (exact: the Schur complement of the full tangent),
a dense system for the vertebra increments and back-substitution; the line search
judges progress by the energy minus the linearised work of the dead moments; load
stepping as for the segment (:func:`.newton.march`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from vertebra.designer.nonlinear.framed import Pose
from vertebra.designer.nonlinear.krylov import ReusedFactorSolver
from vertebra.designer.nonlinear.fe_newton import NewtonSettings, Step, march
from vertebra.core.errors import OptionError
from vertebra.core.lie import hat, qfrom_matrix, so3_expm1, so3_log


@dataclass
class VertebraMass:
    """Mass (kg) and centre of mass (m, in the vertebra frame) of a rigid vertebra."""

    mass: float = 0.0
    center_of_mass: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        self.center_of_mass = np.asarray(self.center_of_mass, dtype=float).reshape(3)
        if not self.mass >= 0:
            raise OptionError(f"vertebra mass must be >= 0, got {self.mass}", field="mass")


@dataclass
class TrunkLoads:
    """Loads in the world frame. ``forces``/``moments``: {vertebra index: 3-vector} (index 1..m, or
    −1 for the tip); ``gravity``: 3-vector (m/s²) or None; ``pressures``: {segment index: per-cavity
    pressures (Pa)}."""

    forces: dict = field(default_factory=dict)
    moments: dict = field(default_factory=dict)
    gravity: np.ndarray | None = None
    pressures: dict = field(default_factory=dict)


@dataclass(frozen=True)
class TrunkSettings:
    newton: NewtonSettings = NewtonSettings(rtol=1e-9, max_iterations=30)
    first_step: float = 1.0               # first load-step fraction (adaptive afterwards)
    max_step: float = 1.0
    step_rtol: float = 1e-10              # relative residual of the interior linear solves


@dataclass
class TrunkState:
    """Vertebra poses (world) as deviations from rest, ``R = R_rest + dR``, ``t = t_rest + dt`` (kept
    without cancellation), and segment interiors (segment coordinates)."""

    dR: np.ndarray                        # (m + 1, 3, 3)
    dt: np.ndarray                        # (m + 1, 3)
    u: list                               # per segment: interior displacement
    rest_R: np.ndarray = field(repr=False, default=None)
    rest_t: np.ndarray = field(repr=False, default=None)
    loads: dict | None = field(repr=False, default=None)      # the loads this state is in equilibrium with

    @property
    def R(self) -> np.ndarray:
        return self.rest_R + self.dR

    @property
    def t(self) -> np.ndarray:
        return self.rest_t + self.dt

    def copy(self) -> "TrunkState":
        return TrunkState(self.dR.copy(), self.dt.copy(), [u.copy() for u in self.u], self.rest_R, self.rest_t,
                          self.loads)


@dataclass
class TrunkResponse:
    positions: np.ndarray                 # (m + 1, 3) vertebra origins, world
    quaternions: np.ndarray               # (m + 1, 4) [w, x, y, z]
    rotations: np.ndarray                 # (m + 1, 3, 3)
    volumes: list                         # per segment: deformed cavity volumes
    volume_growth: list                   # per segment: volume change from rest
    energy: float
    converged: bool
    iterations: int
    load_steps: int
    timings: dict
    diagnostics: dict
    state: TrunkState = field(repr=False)

    def displacements(self, rest: "TrunkResponse | TrunkState") -> np.ndarray:
        """(m + 1, 6): translation and rotation vector of each vertebra from ``rest``."""
        if isinstance(rest, TrunkResponse):
            rest = rest.state
        dt = self.state.dt - rest.dt
        # exp(w) R_rest' = R: w from R Rᵀ_rest' − I = (dR − dR') R'ᵀ computed without cancellation
        rot = []
        for dR, dR0, R0 in zip(self.state.dR, rest.dR, rest.R):
            M = (dR - dR0) @ R0.T
            rot.append(so3_log(np.eye(3) + M) if np.abs(M).max() > 1e-6 else 0.5 * np.array(
                [M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]]))
        return np.hstack([dt, np.array(rot)])


class NonlinearTrunk:
    """Segments (bottom to top) joined by rigid vertebrae; :meth:`solve` for loads."""

    def __init__(self, segments: list, vertebrae: list | None = None, base_rotation=None, base_position=None,
                 settings: TrunkSettings | None = None):
        if not segments:
            raise OptionError("a trunk needs at least one segment", field="segments")
        self.segments = list(segments)
        m = len(self.segments)
        self.vertebrae = [VertebraMass() for _ in range(m + 1)] if vertebrae is None else list(vertebrae)
        if len(self.vertebrae) != m + 1:
            raise OptionError(f"vertebrae: expected {m + 1} (base included), got {len(self.vertebrae)}",
                              field="vertebrae")
        self.settings = settings or TrunkSettings()
        R0 = np.eye(3) if base_rotation is None else np.asarray(base_rotation, dtype=float)
        t0 = np.zeros(3) if base_position is None else np.asarray(base_position, dtype=float)
        heights = np.concatenate([[0.0], np.cumsum([s.length for s in self.segments])])
        self.rest_R = np.repeat(R0[None], m + 1, axis=0)
        self.rest_t = t0[None, :] + heights[:, None] * R0[:, 2][None, :]
        # one factor cache per segment slot (a repeated segment model has different tangents)
        self.solvers = [ReusedFactorSolver(method=s.solver.method, threshold=s.solver.threshold,
                                           modes=s.solver.modes) for s in self.segments]

    @property
    def n_segments(self) -> int:
        return len(self.segments)

    def rest_state(self) -> TrunkState:
        m = self.n_segments
        return TrunkState(np.zeros((m + 1, 3, 3)), np.zeros((m + 1, 3)),
                          [np.zeros(s.framed.n_interior) for s in self.segments], self.rest_R, self.rest_t)

    def solve(self, loads: TrunkLoads, initial: TrunkState | None = None) -> TrunkResponse:
        """Equilibrium under ``loads`` (load stepping from ``initial``'s loads, or from rest)."""
        start = time.perf_counter()
        problem = _TrunkProblem(self, self._normalise(loads), initial or self.rest_state())
        stats0 = [dict(s.stats) for s in self.solvers]
        s = self.settings
        state, evaluation, report = march(problem, problem, problem.initial, s.newton, first_step=s.first_step,
                                          max_step=s.max_step, stage="nonlinear trunk")
        volumes = [ev.volumes.copy() for ev in evaluation["segments"]]
        diagnostics = {"residual": problem.residual_ratio(state, evaluation), "rtol": s.newton.rtol,
                       "cut_steps": report.cut_steps, "indefinite": report.indefinite,
                       "load_step_history": report.history,
                       "min_jacobian": min(ev.min_jacobian for ev in evaluation["segments"]),
                       "dofs": int(sum(seg.n_dofs for seg in self.segments)),
                       "linear_solver": {k: sum(sv.stats[k] - s0[k] for sv, s0 in zip(self.solvers, stats0))
                                         for k in stats0[0]}}
        return TrunkResponse(
            positions=state.t.copy(), quaternions=qfrom_matrix(state.R),
            rotations=state.R.copy(), volumes=volumes,
            volume_growth=[v - seg.framed.rest_volumes for v, seg in zip(volumes, self.segments)],
            energy=evaluation["energy"], converged=True, iterations=report.newton_iterations,
            load_steps=report.load_steps,
            timings={"total_s": time.perf_counter() - start, "evaluate_s": problem.times["evaluate_s"],
                     "linear_solve_s": problem.times["solve_s"]},
            diagnostics=diagnostics, state=state)

    def _normalise(self, loads: TrunkLoads) -> dict:
        m = self.n_segments
        forces = np.zeros((m + 1, 3))
        moments = np.zeros((m + 1, 3))
        for name, source, target in (("forces", loads.forces, forces), ("moments", loads.moments, moments)):
            for k, value in source.items():
                index = k + m + 1 if k < 0 else k
                if not 1 <= index <= m:
                    raise OptionError(f"vertebra index {k} out of range 1..{m} (or -1 for the tip)", field=name)
                target[index] += np.asarray(value, dtype=float).reshape(3)
        pressures = [np.zeros(seg.n_cavities) for seg in self.segments]
        for s, value in loads.pressures.items():
            if not 0 <= s < m:
                raise OptionError(f"segment index {s} out of range 0..{m - 1}", field="pressures")
            p = np.asarray(value, dtype=float).reshape(-1)
            if p.size != self.segments[s].n_cavities:
                raise OptionError(f"segment {s}: expected {self.segments[s].n_cavities} pressures, got {p.size}",
                                  field="pressures")
            pressures[s] = p
        gravity = None if loads.gravity is None else np.asarray(loads.gravity, dtype=float).reshape(3)
        return {"forces": forces, "moments": moments, "pressures": pressures, "gravity": gravity}


def _block(R: np.ndarray) -> np.ndarray:
    """blockdiag(R, R, R, R): rotates [v_a; ω_a; v_b; ω_b] from segment to world axes."""
    Q = np.zeros((12, 12))
    for j in range(4):
        Q[3 * j:3 * j + 3, 3 * j:3 * j + 3] = R
    return Q


class _TrunkProblem:
    """Newton problem on (segment interiors, vertebra poses) and the load path λ: 0 → 1."""

    def __init__(self, trunk: NonlinearTrunk, target: dict, initial: TrunkState):
        self.trunk = trunk
        self.target = target
        self.initial = initial.copy()            # the path runs from its loads (none: unloaded) to the target
        if self.initial.loads is None:
            self.initial.loads = self._zero_loads()
        self.times = {"evaluate_s": 0.0, "solve_s": 0.0}
        self.lengths = np.mean([s.length for s in trunk.segments])

    def _zero_loads(self) -> dict:
        t = self.target
        return {"forces": np.zeros_like(t["forces"]), "moments": np.zeros_like(t["moments"]),
                "pressures": [np.zeros_like(p) for p in t["pressures"]], "gravity": None}

    def _loads_at(self, s: float) -> dict:
        a, b = self.initial.loads, self.target
        mix = lambda x, y: x + s * (y - x)   # noqa: E731
        gravity = [g for g in (a["gravity"], b["gravity"]) if g is not None]
        return {"forces": mix(a["forces"], b["forces"]), "moments": mix(a["moments"], b["moments"]),
                "pressures": [mix(x, y) for x, y in zip(a["pressures"], b["pressures"])],
                "gravity": None if not gravity else mix(np.zeros(3) if a["gravity"] is None else a["gravity"],
                                                        np.zeros(3) if b["gravity"] is None else b["gravity"])}

    # ---- load path -------------------------------------------------------------------------
    def advance(self, state: TrunkState, s_from: float, s_to: float) -> TrunkState:
        out = state.copy()
        out.loads = self._loads_at(s_to)
        return out

    def converged(self, state, evaluation, s):
        return state

    # ---- pieces --------------------------------------------------------------------------------
    def _segment_poses(self, state: TrunkState, s: int) -> tuple[dict, np.ndarray]:
        """Poses of segment s's frames in its own coordinates (its rest placement is vertebra s at rest)."""
        trunk = self.trunk
        Rr, tr = trunk.rest_R[s], trunk.rest_t[s]
        poses = {}
        for name, k in (("bottom", s), ("top", s + 1)):
            centre = trunk.segments[s].framed.fe.faces[name]["centre"]
            rest_offset = Rr.T @ (trunk.rest_t[k] - tr) - centre           # ~0: the rest placement
            poses[name] = Pose(Rr.T @ state.R[k], Rr.T @ (state.t[k] - tr),
                               R_minus_I=Rr.T @ (trunk.rest_R[k] - Rr + state.dR[k]),
                               t_from_rest=rest_offset + Rr.T @ state.dt[k])
        return poses, Rr

    def evaluate(self, state: TrunkState, hessian: bool = True) -> dict:
        start = time.perf_counter()
        trunk = self.trunk
        loads = state.loads
        m = trunk.n_segments
        segments = []
        grad_v = np.zeros((m + 1, 6))                     # conservative gradient at each vertebra (world)
        energy = 0.0
        for s, seg in enumerate(trunk.segments):
            poses, Rr = self._segment_poses(state, s)
            gravity = None if loads["gravity"] is None else Rr.T @ loads["gravity"]
            ev = seg.framed.evaluate(state.u[s], poses, loads["pressures"][s], gravity, hessian)
            ev.rotation = Rr
            segments.append(ev)
            Q = _block(Rr)
            g = Q @ ev.gradient_frames
            grad_v[s] += g[:6]
            grad_v[s + 1] += g[6:]
            energy += ev.energy
        energy_v, grad_b, hess_b = self._body_terms(state, loads)
        energy += energy_v
        grad_v += grad_b
        residual = grad_v.copy()
        residual[:, 3:] -= loads["moments"]
        self.times["evaluate_s"] += time.perf_counter() - start
        return {"segments": segments, "energy": energy, "conservative": grad_v, "residual": residual,
                "body_hessian": hess_b, "force_scale": sum(ev.force_scale for ev in segments)
                + float(np.linalg.norm(loads["forces"])) + float(np.linalg.norm(loads["moments"])) / self.lengths,
                "energy_scale": sum(ev.energy_scale for ev in segments) + abs(energy_v)}

    def _body_terms(self, state: TrunkState, loads: dict):
        """Dead forces at vertebra origins and vertebra weights: energy, gradient, Hessian (ωω blocks)."""
        m = self.trunk.n_segments
        grad = np.zeros((m + 1, 6))
        hess = np.zeros((m + 1, 3, 3))
        energy = 0.0
        for k in range(1, m + 1):
            F = loads["forces"][k]
            energy -= float(F @ state.dt[k])
            grad[k, :3] -= F
            body = self.trunk.vertebrae[k]
            if loads["gravity"] is not None and body.mass > 0:
                g = body.mass * loads["gravity"]
                y = state.R[k] @ body.center_of_mass
                energy -= float(g @ (state.dt[k] + state.dR[k] @ body.center_of_mass))
                grad[k, :3] -= g
                grad[k, 3:] -= np.cross(y, g)
                gy = np.outer(g, y)
                hess[k] -= 0.5 * (gy + gy.T) - float(g @ y) * np.eye(3)
        return energy, grad, hess

    def residual_ratio(self, state, evaluation) -> float:
        scale = max(evaluation["force_scale"], 1e-300)
        r = evaluation["residual"][1:]
        parts = [np.linalg.norm(ev.gradient_interior) for ev in evaluation["segments"]]
        parts += [np.linalg.norm(r[:, :3]), np.linalg.norm(r[:, 3:]) / self.lengths]
        worst = max(parts)
        return 0.0 if worst == 0.0 else worst / scale

    def step(self, state, evaluation, shift: float = 0.0, forcing: float = 0.0) -> Step:
        """The condensed Newton step; ``forcing`` is not used: the interior solves build the
        trunk's Schur complement, which must be exact to ``step_rtol`` for the frames' step."""
        start = time.perf_counter()
        trunk = self.trunk
        m = trunk.n_segments
        n = 6 * m
        K = np.zeros((n + 6, n + 6))                      # vertebra 0 included, dropped below
        condensed = []
        info = {}
        for s, ev in enumerate(evaluation["segments"]):
            A = ev.H_ii
            if shift:
                from scipy.sparse import diags
                A = A + shift * diags(np.abs(A.diagonal()))
            X, solve_info = trunk.solvers[s].solve(A, np.column_stack([ev.H_iq, ev.gradient_interior]),
                                                   rtol=trunk.settings.step_rtol)
            if "negative_pivots" in solve_info:
                info["negative_pivots"] = info.get("negative_pivots", 0) + solve_info["negative_pivots"]
            Y, y = X[:, :12], X[:, 12]
            Hqq = ev.H_qq + (shift * np.diag(np.abs(np.diag(ev.H_qq))) if shift else 0.0)
            S = Hqq - ev.H_iq.T @ Y
            Q = _block(ev.rotation)
            idx = np.arange(6 * s, 6 * s + 12)
            K[np.ix_(idx, idx)] += Q @ S @ Q.T
            condensed.append((Y, y))
        # vertebra terms: body Hessians (ωω) and the skew part of the exponential map (−½ m̂)
        conservative = evaluation["conservative"]
        for k in range(m + 1):
            K[6 * k + 3:6 * k + 6, 6 * k + 3:6 * k + 6] += (evaluation["body_hessian"][k]
                                                           - 0.5 * hat(conservative[k, 3:]))
        rhs = self._condensed_rhs(evaluation, condensed)
        free = np.arange(6, n + 6)
        dq = np.zeros(n + 6)
        dq[free] = np.linalg.solve(K[np.ix_(free, free)], rhs[free])
        du = []
        for s, (Y, y) in enumerate(condensed):
            Q = _block(evaluation["segments"][s].rotation)
            dq_local = Q.T @ dq[6 * s:6 * s + 12]
            du.append(-(y + Y @ dq_local))
        direction = {"dq": dq.reshape(m + 1, 6), "du": du}
        slope = float(sum(ev.gradient_interior @ d for ev, d in zip(evaluation["segments"], du))
                      + evaluation["residual"].reshape(-1) @ dq)
        self.times["solve_s"] += time.perf_counter() - start
        return Step(direction=direction, slope=slope, info=info)

    def _condensed_rhs(self, evaluation, condensed) -> np.ndarray:
        """−(condensed residual) at each vertebra: segment frame gradients corrected for the interior
        residual (``g_q − H_qi H_ii⁻¹ g_i``), body terms, minus the dead moments."""
        m = self.trunk.n_segments
        r = evaluation["residual"].copy()
        for s, (ev, (Y, y)) in enumerate(zip(evaluation["segments"], condensed)):
            Q = _block(ev.rotation)
            correction = Q @ (ev.H_iq.T @ y)
            r[s] -= correction[:6]
            r[s + 1] -= correction[6:]
        return -r.reshape(-1)

    def retract(self, state: TrunkState, step: Step, alpha: float) -> TrunkState:
        dq = step.direction["dq"]
        out = state.copy()
        R = state.R
        for k in range(1, self.trunk.n_segments + 1):
            out.dt[k] += alpha * dq[k, :3]
            out.dR[k] += so3_expm1(alpha * dq[k, 3:]) @ R[k]       # exp(ω)R − R_rest
        out.u = [u + alpha * d for u, d in zip(state.u, step.direction["du"])]
        return out

    def merit(self, state: TrunkState, step: Step | None = None, alpha: float = 0.0, evaluation=None) -> float:
        """Energy (from ``evaluation`` when given) minus the linearised work of the dead moments
        along the current step."""
        start = time.perf_counter()
        trunk = self.trunk
        loads = state.loads
        if evaluation is not None:
            value = evaluation["energy"]
        else:
            value = self._body_terms(state, loads)[0]
            for s, seg in enumerate(trunk.segments):
                poses, Rr = self._segment_poses(state, s)
                gravity = None if loads["gravity"] is None else Rr.T @ loads["gravity"]
                value += seg.framed.energy(state.u[s], poses, loads["pressures"][s], gravity)[0]
        if step is not None:
            value -= alpha * float(np.sum(loads["moments"] * step.direction["dq"][:, 3:]))
        self.times["evaluate_s"] += time.perf_counter() - start
        return value

    def merit_scale(self, evaluation) -> float:
        return evaluation["energy_scale"]
