"""A segment's solid tied to two rigid frames: the potential as a function of the interior
displacements and the poses of the bottom (a) and top (b) frames, with exact derivatives.

Coordinates are the segment's own (frame a at rest at the origin, b at ``(0, 0, L)``).
The nodes of end face ``f`` follow its frame exactly: ``x = t_f + R_f r`` with ``r``
the node's offset from the face centre ``c_f`` in the reference configuration.
Frame increments use the frame-origin parametrisation ``ζ_f = [v; ω]``:
``t_f ← t_f + v``, ``R_f ← exp(ω̂) R_f`` (ω in the segment's axes), so that

    x_a(ζ) = x_a + v + ω × y_a + ½ ω × (ω × y_a) + O(ζ³),   y_a = R_f r_a,

``∂x_a/∂ζ = [I, −ŷ_a]`` and the second-order term gives the geometric stiffness
``Σ_a ½(g_a y_aᵀ + y_a g_aᵀ) − (g_a·y_a) I`` in the ωω block (``g_a = ∂Π/∂x_a``).

Potential: ``Π = U(u) − Σ_k p_k V_k − Σ_dof m_dof g·u``, with ``V_k`` the volume of
cavity k bounded by its deformed walls and two planar caps carried rigidly by the
frames. A cap of area ``A`` on face f with rest normal ``n0`` (out of the cavity:
``+e_z`` on the top face, ``−e_z`` on the bottom one) contributes
``⅓ ∫ x·n dA = ⅓ A (t_f · R_f n0)``: its plane passes through the frame origin.
With ``m = R_f n0``, its gradient is ``⅓A [m; m × t]`` and its Hessian
``⅓A [[0, −m̂], [m̂, ½(t mᵀ + m tᵀ) − (t·m) I]]``. The cap areas come from the
wall integrals by the divergence theorem (``designer.fem``), so walls + caps
are closed on the discrete geometry and ``V`` is the exact enclosed volume.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vertebra.core.lie import hat, se3_exp_matrix, se3_log_matrix
from vertebra.designer.nonlinear.fe_assembly import SolidModel

FACES = ("bottom", "top")
#: outward normal of the cavity on each cap, in the frame of the face
CAP_NORMALS = {"bottom": np.array([0.0, 0.0, -1.0]), "top": np.array([0.0, 0.0, 1.0])}


@dataclass
class Pose:
    """A frame: rotation ``R`` and origin ``t`` (segment coordinates).

    ``R_minus_I`` and ``t_from_rest`` (``t`` minus the face centre at rest), when given, are the
    same pose kept without cancellation: the face displacements are formed from them, so loads
    of 1e-8 of the working range stay resolved (a position of 0.1 m holds only ~1e-17 m)."""

    R: np.ndarray
    t: np.ndarray
    R_minus_I: np.ndarray | None = None
    t_from_rest: np.ndarray | None = None

    def __post_init__(self):
        self.R = np.asarray(self.R, dtype=float).reshape(3, 3)
        self.t = np.asarray(self.t, dtype=float).reshape(3)

    def deviation(self, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(R − I, t − centre)``."""
        dR = self.R - np.eye(3) if self.R_minus_I is None else self.R_minus_I
        dt = self.t - centre if self.t_from_rest is None else self.t_from_rest
        return dR, dt


@dataclass
class FramedEvaluation:
    """Potential and derivatives with respect to (interior displacements, ζ_bottom, ζ_top)."""

    energy: float                   # Π
    strain_energy: float
    volumes: np.ndarray             # (n_cav,) deformed cavity volumes
    gradient_interior: np.ndarray   # ∂Π/∂u_i
    gradient_frames: np.ndarray     # (12,) ∂Π/∂[ζ_a; ζ_b]
    dvolume_interior: np.ndarray    # (n_int, n_cav)
    dvolume_frames: np.ndarray      # (12, n_cav)
    force_scale: float              # norm of the internal + pressure + gravity forces (for tolerances)
    energy_scale: float             # sum of magnitudes of the energy terms (round-off level)
    min_jacobian: float
    H_ii: object = None             # sparse ∂²Π/∂u_i²
    H_iq: np.ndarray = None         # (n_int, 12)
    H_qq: np.ndarray = None         # (12, 12), geometric and cap terms included


class FramedSolid:
    """The potential of one segment between two frames (see the module docstring)."""

    def __init__(self, solid: SolidModel):
        fe = solid.fe
        self.solid = solid
        self.fe = fe
        self.length = fe.length
        self.interior = fe.interior()
        self.n_interior = self.interior.size
        self.face_dofs, self.offsets = {}, {}
        for name in FACES:
            dofs = np.asarray(fe.faces[name]["dofs"])                    # sorted: three per node
            self.face_dofs[name] = dofs
            self.offsets[name] = solid.X[dofs].reshape(-1, 3) - fe.faces[name]["centre"]
        self.boundary = np.concatenate([self.face_dofs[n] for n in FACES])
        self.n_face = {name: self.face_dofs[name].size for name in FACES}
        pattern = solid.pattern
        self.block_ii = pattern.sub(self.interior, self.interior)
        self.block_iF = pattern.sub(self.interior, self.boundary)
        self.block_FF = pattern.sub(self.boundary, self.boundary)
        # cap areas of each cavity: A n0 is the cap's unit-pressure force (fem._caps)
        self.cap_areas = np.array([[abs(w[name][2]) for name in FACES] for w in fe.cap_wrenches]).reshape(-1, 2)
        self.rest_volumes = np.asarray(fe.cavity_volumes, dtype=float)
        volume = float(solid.volume_weights.sum()) / 3.0
        self.density = fe.mass / volume if volume > 0 else 0.0

    @property
    def n_cavities(self) -> int:
        return self.solid.n_cavities

    def rest_poses(self) -> dict:
        return {"bottom": Pose(np.eye(3), np.zeros(3)), "top": Pose(np.eye(3), [0.0, 0.0, self.length])}

    def displacement(self, u_interior: np.ndarray, poses: dict) -> np.ndarray:
        """Full nodal displacement: interior values and the faces' rigid motions."""
        u = np.empty(self.solid.n_dofs)
        u[self.interior] = u_interior
        for name in FACES:
            dR, dt = poses[name].deviation(self.fe.faces[name]["centre"])
            u[self.face_dofs[name]] = (dt[None, :] + self.offsets[name] @ dR.T).ravel()
        return u

    def rigid_blend(self, top: Pose) -> np.ndarray:
        """Interior displacement of the rigid blend between frame a at rest (the identity) and ``top``:
        the node at height z moves by ``exp((z/L) ξ^)`` with ``exp(ξ^)`` the motion of the top face
        (exact on the top face, identity on the bottom). Predictors extrapolate the difference
        between the solution and this field, so large rotation steps keep the elements next to
        the rotating face intact."""
        X = self.solid.X[self.interior].reshape(-1, 3)
        c = self.fe.faces["top"]["centre"]
        xi = se3_log_matrix(top.R, top.t - top.R @ c)
        phi = np.clip(X[:, 2] / self.length, 0.0, 1.0)
        R, t = se3_exp_matrix(phi[:, None] * xi)
        return ((R @ X[:, :, None])[:, :, 0] + t - X).ravel()

    def face_positions(self, name: str, pose: Pose) -> np.ndarray:
        """``y = R r`` of the face nodes (n, 3), relative to the frame origin."""
        return self.offsets[name] @ pose.R.T

    def cap_volumes(self, poses: dict) -> np.ndarray:
        out = np.zeros(self.n_cavities)
        for j, name in enumerate(FACES):
            m = poses[name].R @ CAP_NORMALS[name]
            out += self.cap_areas[:, j] * float(poses[name].t @ m) / 3.0
        return out

    def energy(self, u_interior, poses, pressures, gravity=None) -> tuple[float, float]:
        """``(Π, min J)`` only (line searches)."""
        pressures = np.zeros(self.n_cavities) if pressures is None else np.asarray(pressures, dtype=float)
        u = self.displacement(u_interior, poses)
        ev = self.solid.evaluate(u, order=0)
        volumes = ev.wall_volumes + self.cap_volumes(poses)
        pi = ev.strain_energy - float(np.dot(pressures, volumes)) - self._gravity_work(u, gravity)
        return pi, ev.min_jacobian

    def _gravity_work(self, u, gravity) -> float:
        if gravity is None:
            return 0.0
        return float(np.dot(self._gravity_load(gravity), u))

    def _gravity_load(self, gravity) -> np.ndarray:
        g = np.tile(np.asarray(gravity, dtype=float), self.solid.n_dofs // 3)
        return self.density * self.solid.volume_weights * g

    def evaluate(self, u_interior, poses: dict, pressures, gravity=None, hessian: bool = True) -> FramedEvaluation:
        pressures = np.zeros(self.n_cavities) if pressures is None else np.asarray(pressures, dtype=float)
        u = self.displacement(u_interior, poses)
        ev = self.solid.evaluate(u, pressures, order=2 if hessian else 1)
        n_cav = self.n_cavities
        dV = np.column_stack(ev.wall_gradients) if n_cav else np.zeros((u.size, 0))
        gravity_load = self._gravity_load(gravity) if gravity is not None else np.zeros(u.size)
        grad = ev.internal_force - dV @ pressures - gravity_load
        volumes = ev.wall_volumes + self.cap_volumes(poses)
        energy = ev.strain_energy - float(pressures @ volumes) - float(gravity_load @ u)

        # frame maps: B_f (3n × 6) with rows [I, −ŷ]
        ys = {name: self.face_positions(name, poses[name]) for name in FACES}
        B = {name: self._face_map(ys[name]) for name in FACES}
        g_frames = np.zeros(12)
        dV_frames = np.zeros((12, n_cav))
        for j, name in enumerate(FACES):
            dofs = self.face_dofs[name]
            g_frames[6 * j:6 * j + 6] = B[name].T @ grad[dofs]
            dV_frames[6 * j:6 * j + 6] = B[name].T @ dV[dofs]
        cap_grad, cap_hess = self._cap_terms(poses)                     # (12, n_cav), (n_cav, 12, 12)
        dV_frames += cap_grad
        g_frames -= cap_grad @ pressures
        scale = (np.linalg.norm(ev.internal_force) + np.linalg.norm(dV @ pressures)
                 + np.linalg.norm(gravity_load) + np.linalg.norm(cap_grad @ pressures))
        energy_scale = abs(ev.strain_energy) + float(np.abs(pressures) @ np.abs(volumes)) + abs(float(gravity_load @ u))
        out = FramedEvaluation(energy=energy, strain_energy=ev.strain_energy, volumes=volumes,
                               gradient_interior=grad[self.interior], gradient_frames=g_frames,
                               dvolume_interior=dV[self.interior], dvolume_frames=dV_frames,
                               force_scale=float(scale), energy_scale=energy_scale,
                               min_jacobian=ev.min_jacobian)
        if not hessian:
            return out
        data = ev.hessian_data
        out.H_ii = self.block_ii.matrix(data)
        Bfull = np.zeros((self.boundary.size, 12))
        nb = self.n_face["bottom"]
        Bfull[:nb, :6] = B["bottom"]
        Bfull[nb:, 6:] = B["top"]
        out.H_iq = self.block_iF.matrix(data) @ Bfull
        H_qq = Bfull.T @ (self.block_FF.matrix(data) @ Bfull)
        for j, name in enumerate(FACES):
            g = grad[self.face_dofs[name]].reshape(-1, 3)
            y = ys[name]
            gy = g.T @ y                                                 # Σ g yᵀ
            H_qq[6 * j + 3:6 * j + 6, 6 * j + 3:6 * j + 6] += 0.5 * (gy + gy.T) - np.trace(gy) * np.eye(3)
        H_qq -= np.einsum("k,kab->ab", pressures, cap_hess)
        out.H_qq = 0.5 * (H_qq + H_qq.T)
        return out

    @staticmethod
    def _face_map(y: np.ndarray) -> np.ndarray:
        n = y.shape[0]
        B = np.zeros((n, 3, 6))
        B[:, :, :3] = np.eye(3)
        B[:, 0, 4], B[:, 0, 5] = y[:, 2], -y[:, 1]          # −ŷ = [[0, z, −y], [−z, 0, x], [y, −x, 0]]
        B[:, 1, 3], B[:, 1, 5] = -y[:, 2], y[:, 0]
        B[:, 2, 3], B[:, 2, 4] = y[:, 1], -y[:, 0]
        return B.reshape(3 * n, 6)

    def _cap_terms(self, poses):
        n_cav = self.n_cavities
        grad = np.zeros((12, n_cav))
        hess = np.zeros((n_cav, 12, 12))
        for j, name in enumerate(FACES):
            t = poses[name].t
            m = poses[name].R @ CAP_NORMALS[name]
            g = np.concatenate([m, np.cross(m, t)])
            tm = np.outer(t, m)
            Hc = np.zeros((6, 6))
            Hc[:3, 3:] = -hat(m)
            Hc[3:, :3] = hat(m)
            Hc[3:, 3:] = 0.5 * (tm + tm.T) - float(t @ m) * np.eye(3)
            third = self.cap_areas[:, j] / 3.0
            grad[6 * j:6 * j + 6] = g[:, None] * third[None, :]
            hess[:, 6 * j:6 * j + 6, 6 * j:6 * j + 6] = third[:, None, None] * Hc[None]
        return grad, hess
