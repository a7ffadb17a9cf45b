"""Geometrically nonlinear FE of one segment under an imposed end pose and cavity pressures.

Set-up: the bottom face is clamped to frame ``a`` (the identity), the top face
follows frame ``b`` exactly, ``x = t + R (X − c_b)`` for its nodes (``c_b = (0, 0, L)``
the face centre; any rotation size), and the interior nodes are in equilibrium.
With ``T_b = (R, t)`` the pose of ``b`` in ``a`` and ``p`` the cavity pressures,

    ψ(T_b, p) = min over interior displacements of  Π = ∫ W dV − Σ_k p_k V_k(x),

``V_k`` the deformed volume of cavity k (walls and the two rigid caps, so the
pressure is a follower load and its load stiffness is exact, :mod:`.framed`).

Response conventions (:class:`SegmentResponse`, all in ``a``'s axes, SI units):

* ``wrench`` (6,) ``= ∂ψ/∂ζ`` for the left perturbation ``T_b → exp(ζ^) T_b``,
  ``ζ = [v; ω]``: the force and the moment about ``a``'s origin that must act on
  frame ``b`` to hold it at the pose (``wrench_at_b``: the same force, moment about
  ``b``'s origin).
* ``tangent`` (6, 6): the symmetric Hessian of ``ζ ↦ ψ(exp(ζ^) T_b, p)`` at ``ζ = 0``
  (condensed FE tangent plus the geometric terms of the moving face).
* ``volumes`` (n_cav,) deformed cavity volumes ``= −∂ψ/∂p``; ``volume_growth`` their
  change from rest; ``dvolume_dpose`` (n_cav, 6) ``= ∂V/∂ζ`` and
  ``dvolume_dpressure`` (n_cav, n_cav) ``= ∂V/∂p``. Reciprocity:
  ``∂wrench/∂p = −dvolume_doseᵀ``.
* ``state``: pass as ``initial=`` to continue from this solution (load stepping
  starts there; the interior is predicted with the stored tangent).

Solution: Newton on Π with a line search, load stepping along the straight line
in ``log_SE3(T_b)`` (and in ``p``) from the initial state, linear solves by
:class:`.krylov.ReusedFactorSolver` (SuperLU or AMG-preconditioned CG, one factor
reused across iterations and poses). Failure — including a limit point, where the
tangent loses positive definiteness and the load step cannot be cut further —
raises :class:`ConvergenceError` naming the stage.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from vertebra.designer.families import canonical_parameters, family_of, resolve_mesh_size
from vertebra.designer.fem import build_fe, rigid_body_modes
from vertebra.designer.geometry import mesh_segment
from vertebra.designer.nonlinear.fe_assembly import SolidModel
from vertebra.designer.nonlinear.framed import FramedSolid, Pose
from vertebra.designer.nonlinear.krylov import ReusedFactorSolver
from vertebra.designer.nonlinear.fe_newton import NewtonSettings, Step, march
from vertebra.designer.nonlinear.materials import get_material
from vertebra.core.errors import OptionError
from vertebra.core.lie import hat, se3_exp_matrix, se3_log_matrix, so3_exp, so3_log


@dataclass(frozen=True)
class SegmentSettings:
    """Solver settings: Newton tolerances and the load-step size limits per step."""

    newton: NewtonSettings = NewtonSettings()
    max_rotation_step: float = 0.35          # rad of frame b per load step
    max_translation_step: float = 0.1        # fraction of the segment length per load step
    max_pressure_step: float = 0.05          # fraction of Young's modulus per load step
    step_rtol: float = 1e-8                  # tightest relative residual of a Newton-step linear solve
    #                                          (looser while far from convergence: fe_newton.forcing)
    tangent_rtol: float = 1e-6               # relative residual of the condensed-tangent solves (stationary form)


@dataclass
class SegmentState:
    """A converged solution (opaque: pass back as ``initial=``)."""

    R: np.ndarray
    t: np.ndarray
    pressures: np.ndarray
    u_interior: np.ndarray
    du_dpose: np.ndarray | None = None       # (n_int, 6) in frame-origin coordinates of b
    du_dpressure: np.ndarray | None = None   # (n_int, n_cav)
    condensed: dict | None = None            # frame-origin stiffness, volume derivatives
    # the last solve's increment (scaled: translation / L, rotation, pressure / E) and the error of
    # its first-order (tangent) predictor: the second-order term the next, similar step extrapolates
    increment: np.ndarray | None = None
    remainder: np.ndarray | None = None

    def poses(self) -> dict:
        return {"bottom": Pose(np.eye(3), np.zeros(3)), "top": Pose(self.R, self.t)}


@dataclass
class SegmentResponse:
    """Equilibrium at one pose (conventions in the module docstring)."""

    R: np.ndarray
    t: np.ndarray
    pressures: np.ndarray
    energy: float                 # ψ
    strain_energy: float          # ∫ W dV
    wrench: np.ndarray            # (6,)
    tangent: np.ndarray           # (6, 6)
    volumes: np.ndarray           # (n_cav,)
    volume_growth: np.ndarray     # (n_cav,)
    dvolume_dpose: np.ndarray     # (n_cav, 6)
    dvolume_dpressure: np.ndarray  # (n_cav, n_cav)
    converged: bool
    iterations: int
    load_steps: int
    timings: dict
    diagnostics: dict
    state: SegmentState = field(repr=False)

    @property
    def wrench_at_b(self) -> np.ndarray:
        """Force and moment about ``b``'s origin (``a``'s axes)."""
        f = self.wrench[:3]
        return np.concatenate([f, self.wrench[3:] - np.cross(self.t, f)])


#: cosine between consecutive solves' increments above which the second-order term of the last
#: one's predictor is extrapolated into the next prediction
SECOND_ORDER_COSINE = 0.9


def left_from_frame_origin(t: np.ndarray) -> np.ndarray:
    """``J`` with ``ζ_frame-origin = J ζ_left`` to first order: ``v_f = v + ω × t``."""
    J = np.eye(6)
    J[:3, 3:] = -hat(t)
    return J


class NonlinearSegment:
    """Nonlinear FE model of one segment (build once, :meth:`solve` many poses)."""

    def __init__(self, framed: FramedSolid, settings: SegmentSettings | None = None, linear_solver: str = "auto",
                 amg_threshold: int | None = None):
        self.framed = framed
        self.settings = settings or SegmentSettings()
        fe = framed.fe
        modes = rigid_body_modes(fe.doflocs[:, framed.interior], fe.components[framed.interior])
        kwargs = {} if amg_threshold is None else {"threshold": amg_threshold}
        self.solver = ReusedFactorSolver(method=linear_solver, modes=modes, **kwargs)
        self._rest = None
        self.mesh_data = None           # the MeshData it was built from (for exporting the same mesh)

    # ---- construction ------------------------------------------------------------------------
    @classmethod
    def build(cls, mesh_data, material, *, density: float = 0.0, n_cavities: int = 0, length: float,
              settings: SegmentSettings | None = None, linear_solver: str = "auto",
              amg_threshold: int | None = None) -> "NonlinearSegment":
        """From a mesh (:class:`vertebra.designer.geometry.MeshData`) and a material
        (:func:`.materials.get_material`)."""
        fe = build_fe(mesh_data, material.youngs_modulus, material.poisson_ratio, density, n_cavities, length)
        segment = cls(FramedSolid(SolidModel(fe, material)), settings, linear_solver, amg_threshold)
        segment.mesh_data = mesh_data
        return segment

    @classmethod
    def from_family(cls, family, parameters: dict, material: str = "neo_hookean", *, mesh_size=None,
                    order: int = 2, **kwargs) -> "NonlinearSegment":
        """Mesh a designer family (``designer.FAMILIES``) and build the model; the material constants
        are the family's ``youngs_modulus``, ``poisson_ratio`` and ``density``."""
        fam = family_of(family)
        p = canonical_parameters(fam, parameters)
        mesh = mesh_segment(fam, p, resolve_mesh_size(fam, p, mesh_size), order)
        return cls.build(mesh, get_material(material, p["youngs_modulus"], p["poisson_ratio"]),
                         density=p["density"], n_cavities=fam.n_cavities(p), length=fam.length(p), **kwargs)

    # ---- properties --------------------------------------------------------------------------
    @property
    def length(self) -> float:
        return self.framed.length

    @property
    def n_cavities(self) -> int:
        return self.framed.n_cavities

    @property
    def n_dofs(self) -> int:
        return self.framed.solid.n_dofs

    @property
    def material(self):
        return self.framed.solid.material

    @property
    def rest_volumes(self) -> np.ndarray:
        return self.framed.rest_volumes.copy()

    def rest_pose(self) -> tuple[np.ndarray, np.ndarray]:
        return np.eye(3), np.array([0.0, 0.0, self.length])

    def rest_state(self) -> SegmentState:
        """The unloaded state with its tangent data (computed once)."""
        if self._rest is None:
            R, t = self.rest_pose()
            state = SegmentState(R, t, np.zeros(self.n_cavities), np.zeros(self.framed.n_interior))
            problem = _PoseProblem(self, state, state, gravity=None)
            self._rest = problem.converged(state, problem.evaluate(state, hessian=True))
        return self._rest

    # ---- solve -------------------------------------------------------------------------------
    def solve(self, R, t, pressures=None, initial: SegmentState | None = None, gravity=None,
              min_load_step: float | None = None) -> SegmentResponse:
        """Equilibrium with frame ``b`` at ``(R, t)`` (in ``a``), cavity pressures ``pressures`` (Pa) and an
        optional gravity vector (m/s², in ``a``'s axes) on the segment's own mass. ``min_load_step``:
        give up once a load step is cut below it (default: the settings' ``newton.min_step``) —
        for callers that expect a failure and handle it cheaply."""
        start = time.perf_counter()
        target = self._target(R, t, pressures)
        initial = self.rest_state() if initial is None else initial
        if initial.u_interior.shape != (self.framed.n_interior,):
            raise OptionError("initial: state of another segment model", field="initial")
        stats0 = dict(self.solver.stats)
        problem = _PoseProblem(self, initial, target, gravity)
        newton = self.settings.newton
        if min_load_step is not None:
            newton = replace(newton, min_step=max(newton.min_step, min_load_step))
        state, evaluation, report = march(problem, problem, initial, newton,
                                          first_step=problem.first_step(), max_step=min(1.0, 2 * problem.first_step()),
                                          stage="nonlinear segment")
        response = self._response(state, evaluation, report, problem)
        response.timings.update({"total_s": time.perf_counter() - start})
        response.diagnostics["linear_solver"] = {k: self.solver.stats[k] - stats0[k] for k in stats0}
        return response

    def _target(self, R, t, pressures) -> SegmentState:
        R = np.asarray(R, dtype=float)
        t = np.asarray(t, dtype=float)
        if R.shape != (3, 3) or not np.allclose(R.T @ R, np.eye(3), atol=1e-9) or np.linalg.det(R) <= 0:
            raise OptionError("R must be a 3×3 rotation matrix", field="R")
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise OptionError("t must be a finite 3-vector", field="t")
        p = np.zeros(self.n_cavities) if pressures is None else np.asarray(pressures, dtype=float).reshape(-1)
        if p.shape != (self.n_cavities,):
            raise OptionError(f"pressures: expected {self.n_cavities} values, got {p.size}", field="pressures")
        return SegmentState(R, t, p, np.zeros(0))

    def _response(self, state: SegmentState, evaluation, report, problem) -> SegmentResponse:
        c = state.condensed
        J = left_from_frame_origin(state.t)
        w_f = c["wrench"]
        F = w_f[:3]
        tangent = J.T @ c["stiffness"] @ J
        Ft = np.outer(F, state.t)
        tangent[3:, 3:] += 0.5 * (Ft + Ft.T) - float(F @ state.t) * np.eye(3)
        tangent[:3, 3:] += 0.5 * hat(F)
        tangent[3:, :3] -= 0.5 * hat(F)
        tangent = 0.5 * (tangent + tangent.T)
        volumes = c["volumes"]
        diagnostics = {"residual": problem.residual_ratio(state, evaluation), "rtol": self.settings.newton.rtol,
                       "min_jacobian": evaluation.min_jacobian, "cut_steps": report.cut_steps,
                       "indefinite": report.indefinite, "negative_pivots": report.negative_pivots,
                       "load_step_history": report.history, "dofs": self.n_dofs,
                       "interior_dofs": self.framed.n_interior}
        return SegmentResponse(
            R=state.R.copy(), t=state.t.copy(), pressures=state.pressures.copy(), energy=c["energy"],
            strain_energy=evaluation.strain_energy, wrench=J.T @ w_f, tangent=tangent, volumes=volumes.copy(),
            volume_growth=volumes - self.framed.rest_volumes, dvolume_dpose=c["dvolume_dpose"] @ J,
            dvolume_dpressure=c["dvolume_dpressure"], converged=True, iterations=report.newton_iterations,
            load_steps=report.load_steps,
            timings={"newton_s": report.time_s, "evaluate_s": problem.times["evaluate_s"],
                     "linear_solve_s": problem.times["solve_s"]},
            diagnostics=diagnostics, state=state)


class _PoseProblem:
    """Newton problem (interior displacements at fixed frames) and load path from ``initial`` to ``target``."""

    def __init__(self, segment: NonlinearSegment, initial: SegmentState, target: SegmentState, gravity):
        self.segment = segment
        self.framed = segment.framed
        self.settings = segment.settings
        self.gravity = None if gravity is None else np.asarray(gravity, dtype=float).reshape(3)
        self.xi0 = se3_log_matrix(initial.R, initial.t)
        self.xi1 = se3_log_matrix(target.R, target.t)
        self.p0 = initial.pressures
        self.p1 = target.pressures
        self.times = {"evaluate_s": 0.0, "solve_s": 0.0}
        # (s, u_interior − rigid blend) of the last converged states on this path
        self.history = [(0.0, initial.u_interior - self.framed.rigid_blend(Pose(initial.R, initial.t)))]
        self.first_order = None          # (increment, first-order prediction) of a whole-path first step

    def first_step(self) -> float:
        s = self.settings
        R0, t0 = se3_exp_matrix(self.xi0)
        R1, t1 = se3_exp_matrix(self.xi1)
        E = self.segment.material.youngs_modulus
        steps = max(np.linalg.norm(so3_log(R1 @ R0.T)) / s.max_rotation_step,
                    np.linalg.norm(t1 - t0) / (s.max_translation_step * self.segment.length),
                    float(np.max(np.abs(self.p1 - self.p0), initial=0.0)) / (s.max_pressure_step * E), 1.0)
        return 1.0 / math.ceil(steps - 1e-9)

    # ---- load path -------------------------------------------------------------------------
    def advance(self, state: SegmentState, s_from: float, s_to: float) -> SegmentState:
        """Pose and pressures at ``s_to``; the interior predicted on top of the rigid blend of the
        frames (:meth:`FramedSolid.rigid_blend`): by the secant through the last two converged
        states of this path, or (first step) by the initial state's tangent."""
        R, t = se3_exp_matrix(self.xi0 + s_to * (self.xi1 - self.xi0))
        p = self.p0 + s_to * (self.p1 - self.p0)
        blend = self.framed.rigid_blend(Pose(R, t))
        if len(self.history) == 2:
            (s0, w0), (s1, w1) = self.history
            return SegmentState(R, t, p, blend + w1 + (s_to - s1) / (s1 - s0) * (w1 - w0))
        u = state.u_interior.copy()
        if state.du_dpose is not None:
            dzeta = np.concatenate([t - state.t, so3_log(R @ state.R.T)])
            blend0 = self.framed.rigid_blend(Pose(state.R, state.t))
            # the tangent's change minus the blend's first-order change, plus the blend's exact change
            eps = 1e-4 / max(np.linalg.norm(dzeta[3:]), np.linalg.norm(dzeta[:3]) / self.segment.length, 1e-300)
            plus, minus = (self.framed.rigid_blend(Pose(so3_exp(h * dzeta[3:]) @ state.R, state.t + h * dzeta[:3]))
                           for h in (eps, -eps))
            u += (blend - blend0) + state.du_dpose @ dzeta - (plus - minus) / (2 * eps)
            if p.size:
                u += state.du_dpressure @ (p - state.pressures)
            increment = np.concatenate([dzeta[:3] / self.segment.length, dzeta[3:],
                                        (p - state.pressures) / self.segment.material.youngs_modulus])
            if s_to == 1.0:
                self.first_order = (increment, u.copy())
            u += self._second_order(state, increment)
        return SegmentState(R, t, p, u)

    @staticmethod
    def _second_order(state: SegmentState, increment: np.ndarray):
        """The previous solve's predictor error scaled to this increment (``ratio²``, ratio the
        projection of this increment on that one's) when the two are nearly parallel — along a
        loading path, consecutive samples: the second-order term of the path's extrapolation."""
        if state.remainder is None or state.increment is None or state.increment.shape != increment.shape:
            return 0.0
        last = state.increment
        norms = float(np.linalg.norm(last) * np.linalg.norm(increment))
        if norms == 0.0 or float(last @ increment) < SECOND_ORDER_COSINE * norms:
            return 0.0
        ratio = float(last @ increment) / float(last @ last)
        return ratio ** 2 * state.remainder if ratio <= 2.0 else 0.0

    def converged(self, state: SegmentState, evaluation, s: float = 1.0) -> SegmentState:
        """Remember the state for the secant predictor; at the end of the path (``s = 1``) add the
        condensed tangent (frame-origin coordinates of b) and the predictor's derivatives.

        The remaining interior residual ``g_i`` (within tolerance) is taken out to first
        order: ``y = H_ii⁻¹ g_i`` corrects the wrench (``g_b − H_biy``), the volumes
        (``V − ∂V/∂u_i · y``) and ψ (``Π − ½ g_i·y``).

        The condensed second derivatives ``Bᵀ H_ii⁻¹ B`` (``B = [H_iq, ∂V/∂u_i]``) are taken in
        their stationary form ``BᵀX + XᵀB − Xᵀ H_ii X`` with ``X ≈ H_ii⁻¹ B``: its error is
        quadratic in the solve's, so ``tangent_rtol`` can stay loose (1e-6 gives ~1e-12)."""
        remainder = state.u_interior - self.framed.rigid_blend(Pose(state.R, state.t))
        self.history = (self.history + [(s, remainder)])[-2:]
        if s < 1.0:
            return state
        start = time.perf_counter()
        H_iq = evaluation.H_iq[:, 6:]
        dV_i = evaluation.dvolume_interior
        g_i = evaluation.gradient_interior
        X, _ = self.segment.solver.solve(evaluation.H_ii, np.column_stack([H_iq, dV_i, g_i]),
                                         rtol=self.settings.tangent_rtol)
        self.times["solve_s"] += time.perf_counter() - start
        Xq, Xp, y = X[:, :6], X[:, 6:-1], X[:, -1]
        B, XB = np.column_stack([H_iq, dV_i]), X[:, :-1]
        BX = B.T @ XB
        M = BX + BX.T - XB.T @ (evaluation.H_ii @ XB)                  # stationary Bᵀ H_ii⁻¹ B
        M = 0.5 * (M + M.T)
        condensed = {"stiffness": evaluation.H_qq[6:, 6:] - M[:6, :6],
                     "wrench": evaluation.gradient_frames[6:] - H_iq.T @ y,
                     "volumes": evaluation.volumes - dV_i.T @ y,
                     "energy": evaluation.energy - 0.5 * float(g_i @ y),
                     "dvolume_dpose": evaluation.dvolume_frames[6:].T - M[6:, :6],
                     "dvolume_dpressure": M[6:, 6:]}
        increment, remainder = None, None
        if self.first_order is not None and len(self.history) == 2 and self.history[0][0] == 0.0:
            increment, remainder = self.first_order[0], state.u_interior - y - self.first_order[1]
        return SegmentState(state.R, state.t, state.pressures, state.u_interior - y, du_dpose=-Xq,
                            du_dpressure=Xp, condensed=condensed, increment=increment, remainder=remainder)

    # ---- Newton problem ----------------------------------------------------------------------
    def evaluate(self, state: SegmentState, hessian: bool = True):
        start = time.perf_counter()
        out = self.framed.evaluate(state.u_interior, state.poses(), state.pressures, self.gravity, hessian)
        self.times["evaluate_s"] += time.perf_counter() - start
        return out

    def residual_ratio(self, state, evaluation) -> float:
        r = float(np.linalg.norm(evaluation.gradient_interior))
        return 0.0 if r == 0.0 else r / max(evaluation.force_scale, 1e-300)

    def step(self, state, evaluation, shift: float = 0.0, forcing: float = 0.0) -> Step:
        start = time.perf_counter()
        A = evaluation.H_ii
        if shift:
            A = A + shift * _diagonal(A)
        g = evaluation.gradient_interior
        d, info = self.segment.solver.solve(A, -g, rtol=max(self.settings.step_rtol, forcing))
        self.times["solve_s"] += time.perf_counter() - start
        return Step(direction=d, slope=float(g @ d), info=info)

    def retract(self, state: SegmentState, step: Step, alpha: float) -> SegmentState:
        return SegmentState(state.R, state.t, state.pressures, state.u_interior + alpha * step.direction)

    def merit(self, state: SegmentState, step: Step | None = None, alpha: float = 0.0, evaluation=None) -> float:
        if evaluation is not None:
            return evaluation.energy
        start = time.perf_counter()
        value = self.framed.energy(state.u_interior, state.poses(), state.pressures, self.gravity)[0]
        self.times["evaluate_s"] += time.perf_counter() - start
        return value

    def merit_scale(self, evaluation) -> float:
        return evaluation.energy_scale


def _diagonal(A):
    from scipy.sparse import diags
    return diags(np.abs(A.diagonal()))
