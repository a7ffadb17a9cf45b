"""Fit a segment's energy ψ(s, p) to sampled nonlinear responses (nonlinear condensation).

The samples are equilibria of the segment's solid with its top frame at a prescribed pose and
its cavities at prescribed pressures: the load conjugate to the pose (a wrench), the tangent,
the cavity volume growths and their derivatives. :func:`strain_derivatives` turns the
FE's pose chart (a left perturbation ``exp(ζ^) T`` of frame b, in a's axes) into the strain
chart of ψ (``s = log(T_a⁻¹T_b) − ξ₀``). :func:`fit_energy` then solves one linear least
squares problem for ψ_nl (core.energy): gradients (loads and volume growths) and Hessians
(tangents) of ψ matched in scaled variables, the linear part fixed (so the Hessian at rest is
the linear compliance's, exactly), over a basis of polynomials invariant under the
segment's symmetry group (:func:`symmetry_group`, :func:`invariant_basis`). Symmetry makes
ψ exact-invariant and cuts the unknowns: a rod's degree-6 fit has 60 of 896.

Chart relations, with ``J⁻¹ = J_l⁻¹(ξ)`` the inverse left Jacobian (``log(exp(ζ^)T) = ξ + J⁻¹ζ +
O(ζ²)``) and ``E(g) = ∂(J⁻ᵀ g)/∂ξ`` at fixed ``g``::

    wrench = J⁻ᵀ ∂ψ/∂s,   tangent = J⁻ᵀ (∂²ψ/∂s²) J⁻¹ + sym(E(∂ψ/∂s) J⁻¹)

(the skew part of ``E J⁻¹`` is the ½ ad-term of the perturbation's own second order, which
makes the tangent symmetric). ``E`` is taken by fourth-order central differences of
``J_l⁻¹`` (:func:`vertebra.core.lie.se3_left_jacobian_inverse`; error ~1e-12 relative), far
below the FE's own tolerance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vertebra.designer.families import SegmentSymmetry
from vertebra.core.energy import (EnergyFit, EnergyModel, EnergyRange, Monomials, fold_map, group_coordinates,
                                  monomial_exponents)
from vertebra.core.errors import GeometryError
from vertebra.core.lie import se3_exp_matrix, se3_left_jacobian_inverse

#: the largest held-out load error (fraction of the sampled load range) of a fit that may serve:
#: ``vertebra design`` warns above it, ``vertebra prepare`` refuses an entry whose error over the
#: part of its box a scene needs exceeds it (``--max-fit-error`` overrides). Measured: trunks of
#: entries fitted within 0.5–2.7 % were 0.016–0.045 % of their length off a full nonlinear FE to
#: 34–88°; the St Venant–Kirchhoff rod fitted within 28 % was 0.41 % off at 50°
#: (docs/nonlinear-condensation.md)
FIT_LIMIT = 0.05
#: step of the differences for E(g) (rad or m·scale); fourth-order stencil
_DIFFERENCE_STEP = 1e-3


# ------------------------------------------------------------------ SE(3) charts

def pose_of_strain(s: np.ndarray, rest_translation) -> tuple[np.ndarray, np.ndarray]:
    """Rotation matrices (n, 3, 3) and translations (n, 3) of ``exp(ξ₀ + s)``."""
    xi = np.asarray(s, dtype=float).reshape(-1, 6).copy()
    xi[:, :3] += np.asarray(rest_translation, dtype=float)
    return se3_exp_matrix(xi)


def _jacobian_derivative(xi: np.ndarray, g: np.ndarray) -> np.ndarray:
    """``E(g)`` (n, 6, 6): column j is ``∂(J⁻ᵀ(ξ) g)/∂ξ_j`` at fixed ``g`` (fourth-order differences)."""
    n = xi.shape[0]
    out = np.empty((n, 6, 6))
    h = _DIFFERENCE_STEP
    for j in range(6):
        step = np.zeros(6)
        step[j] = h
        values = [se3_left_jacobian_inverse(xi + k * step).mT @ g[:, :, None] for k in (-2, -1, 1, 2)]
        out[:, :, j] = ((values[0] - 8.0 * values[1] + 8.0 * values[2] - values[3]) / (12.0 * h))[:, :, 0]
    return out


def _sym(A: np.ndarray) -> np.ndarray:
    return 0.5 * (A + A.mT)


def strain_derivatives(s: np.ndarray, rest_translation, wrench: np.ndarray, tangent: np.ndarray,
                       wrench_pressure: np.ndarray | None = None):
    """Pose chart → strain chart. ``wrench`` (n, 6) = ∂ψ/∂ζ, ``tangent`` (n, 6, 6) = ∂²ψ/∂ζ²,
    ``wrench_pressure`` (n, 6, m) = ∂²ψ/∂ζ∂p. Returns ``(∂ψ/∂s, ∂²ψ/∂s², ∂²ψ/∂s∂p)``."""
    xi = np.asarray(s, dtype=float).copy()
    xi[:, :3] += np.asarray(rest_translation, dtype=float)
    Ji = se3_left_jacobian_inverse(xi)
    J = np.linalg.inv(Ji)
    g = (J.mT @ wrench[:, :, None])[:, :, 0]                       # ∂ψ/∂s = Jᵀ wrench
    E = _jacobian_derivative(xi, g)
    H = J.mT @ (_sym(tangent) - _sym(E @ Ji)) @ J
    mixed = None if wrench_pressure is None else J.mT @ wrench_pressure
    return g, _sym(H), mixed


def pose_derivatives(s: np.ndarray, rest_translation, gradient: np.ndarray, hessian: np.ndarray,
                     mixed: np.ndarray | None = None):
    """Strain chart → pose chart (the inverse of :func:`strain_derivatives`): ``(∂ψ/∂ζ, ∂²ψ/∂ζ²,
    ∂²ψ/∂ζ∂p)`` from ``(∂ψ/∂s, ∂²ψ/∂s², ∂²ψ/∂s∂p)``."""
    xi = np.asarray(s, dtype=float).copy()
    xi[:, :3] += np.asarray(rest_translation, dtype=float)
    Ji = se3_left_jacobian_inverse(xi)
    wrench = (Ji.mT @ gradient[:, :, None])[:, :, 0]
    E = _jacobian_derivative(xi, gradient)
    tangent = _sym(Ji.mT @ hessian @ Ji) + _sym(E @ Ji)
    return wrench, tangent, None if mixed is None else Ji.mT @ mixed


# ------------------------------------------------------------------ symmetry

def _rotation_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _reflection(angle: float) -> np.ndarray:
    """Mirror across the vertical plane at ``angle`` from +x."""
    c, s = math.cos(2 * angle), math.sin(2 * angle)
    return np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, 1.0]])


def _half_turn(angle: float) -> np.ndarray:
    """Rotation by π about the horizontal axis at ``angle`` from +x."""
    c, s = math.cos(2 * angle), math.sin(2 * angle)
    return np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])


def _element(Q: np.ndarray, flip: bool, angles: np.ndarray) -> np.ndarray:
    """The (6+m)×(6+m) map of ``z = [s; p]`` under an isometry ``Q`` of the segment (composed with
    the exchange of its ends when ``flip``): ``s ↦ ±[Qρ; det(Q) Q φ]``, cavities permuted."""
    m = len(angles)
    L = np.zeros((6 + m, 6 + m))
    sign = -1.0 if flip else 1.0
    L[:3, :3] = sign * Q
    L[3:6, 3:6] = sign * np.linalg.det(Q) * Q
    on_axis = np.array([a is None for a in angles], dtype=bool)
    values = np.array([0.0 if a is None else a for a in angles], dtype=float)
    centres = np.stack([np.cos(values), np.sin(values)], 1) * (~on_axis)[:, None]
    images = centres @ Q[:2, :2].T
    for k in range(m):
        if on_axis[k]:
            L[6 + k, 6 + k] = 1.0
        else:
            target = np.flatnonzero((np.linalg.norm(centres - images[k], axis=1) < 1e-9) & ~on_axis)
            if target.size != 1:
                raise GeometryError(f"symmetry maps cavity {k} onto no cavity: the declared symmetry "
                                    "does not hold for the cavities")
            L[6 + target[0], 6 + k] = 1.0
    return L


def symmetry_group(symmetry: SegmentSymmetry, degree: int) -> list[np.ndarray]:
    """The group's elements as maps of ``z = [s; p]``. An axisymmetric segment is represented by
    the rotations by 2π/(degree + 1): a polynomial of degree ≤ ``degree`` invariant under them
    is invariant under every rotation about the axis (its angular frequencies are ≤ degree)."""
    angles = tuple(symmetry.cavity_angles)
    order = symmetry.order if symmetry.order > 0 else degree + 1
    if symmetry.order == 0 and any(a is not None for a in angles):
        raise GeometryError("an axisymmetric segment cannot have off-axis cavities")
    generators = [_element(_rotation_z(2 * math.pi / order), False, angles)]
    if symmetry.mirror:
        generators.append(_element(_reflection(symmetry.mirror_angle), False, angles))
    if symmetry.end_flip:
        generators.append(_element(_half_turn(symmetry.mirror_angle), True, angles))
    group = [np.eye(6 + len(angles))]
    frontier = list(group)
    while frontier:
        new = []
        for g in frontier:
            for h in generators:
                candidate = h @ g
                if not any(np.allclose(candidate, e, atol=1e-12) for e in group + new):
                    new.append(candidate)
        group += new
        frontier = new
    return group


def _homogeneous(nv: int, k: int, m: int, pressure_degree: int) -> np.ndarray:
    """The monomials of total degree ``k`` a fit uses: those with a pressure only up to
    ``pressure_degree`` (every monomial below degree 3, which the recursions need)."""
    return monomial_exponents(nv, k, k, tail=m, tail_degree=pressure_degree if k >= 3 else None)


def _shift_tables(exponents_by_degree: list[np.ndarray]) -> list:
    """For each degree k ≥ 1 and variable w: (rows of degree k that are a degree-(k−1) monomial
    times u_w, the degree-(k−1) monomials they come from) — products beyond a degree cap dropped."""
    index = [{tuple(r): i for i, r in enumerate(E.tolist())} for E in exponents_by_degree]
    tables = [None]
    for k in range(1, len(exponents_by_degree)):
        per_variable = []
        for w in range(exponents_by_degree[0].shape[1]):
            shifted = exponents_by_degree[k - 1].copy()
            shifted[:, w] += 1
            target = np.array([index[k].get(tuple(r), -1) for r in shifted.tolist()], dtype=np.int64)
            keep = np.flatnonzero(target >= 0)
            per_variable.append((target[keep], keep))
        tables.append(per_variable)
    return tables


def _substitution(exponents_by_degree: list[np.ndarray], L: np.ndarray, shifts: list) -> list[np.ndarray]:
    """For each degree k ≥ 1, the matrix R_k with ``coefficients(f∘L) = R_k coefficients(f)`` on the
    homogeneous monomials of that degree (columns: monomials; rows: monomials of the image)."""
    nv = L.shape[0]
    index = [{tuple(r): i for i, r in enumerate(E.tolist())} for E in exponents_by_degree]
    images = [np.ones((1, 1))]
    for k in range(1, len(exponents_by_degree)):
        E = exponents_by_degree[k]
        last = nv - 1 - np.argmax(E[:, ::-1] > 0, axis=1)
        parents = E.copy()
        parents[np.arange(len(E)), last] -= 1
        parent_index = np.array([index[k - 1][tuple(r)] for r in parents.tolist()])
        prev = images[k - 1]
        img = np.zeros((len(E), len(E)))
        for w in range(nv):
            columns = np.flatnonzero(L[last, w])
            if columns.size == 0:
                continue
            # the image of u^α = image(parent) · (L u)_last: its u_w part lands on parent's rows + e_w
            target, keep = shifts[k][w]
            img[np.ix_(target, columns)] += prev[np.ix_(keep, parent_index[columns])] * L[last[columns], w][None, :]
        images.append(img)
    return images


def invariant_basis(nv: int, m: int, degree: int, pressure_degree: int, group: list[np.ndarray],
                    scales: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(exponents (T, nv), basis (T, q))``: the monomials of degree ≥ 3 of :func:`_homogeneous` in
    the scaled variables ``u = z / scales``, and an orthonormal basis of the polynomials
    invariant under ``group`` (the range of the Reynolds projector ``mean_g f∘g``; the group
    keeps the degrees in ``s`` and in ``p``, so it maps the selection onto itself). Monomials
    no invariant polynomial uses are dropped."""
    scaled = [np.diag(1.0 / scales) @ g @ np.diag(scales) for g in group]
    by_degree = [_homogeneous(nv, k, m, pressure_degree) for k in range(degree + 1)]
    blocks_e, blocks_b = [], []
    totals = [np.zeros((len(E), len(E))) for E in by_degree]
    shifts = _shift_tables(by_degree)
    for L in scaled:
        for k, R in enumerate(_substitution(by_degree, L, shifts)):
            totals[k] += R
    rng = np.random.default_rng(0)
    for k in range(3, degree + 1):
        P = totals[k] / len(scaled)
        # P is a projector: its rank is its trace, and P Ω spans its range for a random Ω
        rank = int(round(np.trace(P)))
        if rank == 0:
            continue
        U, sv, _ = np.linalg.svd(P @ rng.standard_normal((P.shape[0], rank + 8)), full_matrices=False)
        basis = U[:, :rank]
        used = np.linalg.norm(basis, axis=1) > 1e-12
        blocks_e.append(by_degree[k][used])
        blocks_b.append((k, basis[used]))
    exponents = np.concatenate(blocks_e) if blocks_e else np.zeros((0, nv), dtype=np.int64)
    q = sum(b.shape[1] for _, b in blocks_b)
    basis = np.zeros((exponents.shape[0], q))
    row = col = 0
    for _, b in blocks_b:
        basis[row:row + b.shape[0], col:col + b.shape[1]] = b
        row += b.shape[0]
        col += b.shape[1]
    basis[np.abs(basis) < 1e-14] = 0.0
    return exponents, basis


# ------------------------------------------------------------------ samples and fit

@dataclass
class Samples:
    """Sampled equilibria in the strain chart (one row per sample)."""

    strain: np.ndarray               # (S, 6) s
    pressure: np.ndarray             # (S, m)
    gradient: np.ndarray             # (S, 6) ∂ψ/∂s
    hessian: np.ndarray              # (S, 6, 6) ∂²ψ/∂s²
    pressure_gradient: np.ndarray    # (S, m) ∂ψ/∂p = −ΔV
    mixed: np.ndarray                # (S, 6, m) ∂²ψ/∂s∂p
    pressure_hessian: np.ndarray     # (S, m, m) ∂²ψ/∂p²
    path: np.ndarray                 # (S,) index of the loading path (held-out selection)

    def __post_init__(self):
        S = self.strain.shape[0]
        m = self.pressure.shape[1] if self.pressure.ndim == 2 else 0
        shapes = {"strain": (S, 6), "pressure": (S, m), "gradient": (S, 6), "hessian": (S, 6, 6),
                  "pressure_gradient": (S, m), "mixed": (S, 6, m), "pressure_hessian": (S, m, m), "path": (S,)}
        for name, shape in shapes.items():
            value = np.asarray(getattr(self, name))
            if value.shape != shape:
                raise ValueError(f"samples field {name!r}: shape {value.shape}, expected {shape}")
            setattr(self, name, value)

    @property
    def size(self) -> int:
        return self.strain.shape[0]

    @property
    def n_cavities(self) -> int:
        return self.pressure.shape[1]

    def take(self, rows) -> "Samples":
        return Samples(**{name: getattr(self, name)[rows] for name in (
            "strain", "pressure", "gradient", "hessian", "pressure_gradient", "mixed", "pressure_hessian", "path")})

    def variables(self) -> np.ndarray:
        return np.concatenate([self.strain, self.pressure], axis=1)

    def full_gradient(self) -> np.ndarray:
        return np.concatenate([self.gradient, self.pressure_gradient], axis=1)

    def full_hessian(self) -> np.ndarray:
        top = np.concatenate([self.hessian, self.mixed], axis=2)
        bottom = np.concatenate([self.mixed.mT, self.pressure_hessian], axis=2)
        return np.concatenate([top, bottom], axis=1)

    @classmethod
    def concatenate(cls, parts: list["Samples"]) -> "Samples":
        return cls(**{name: np.concatenate([getattr(p, name) for p in parts]) for name in (
            "strain", "pressure", "gradient", "hessian", "pressure_gradient", "mixed", "pressure_hessian", "path")})


def linear_derivatives(z: np.ndarray, K: np.ndarray, S: np.ndarray, V: np.ndarray):
    """Gradient (n, nv) and Hessian (nv, nv) of ψ_lin at ``z = [s; p]`` (core.energy's linear part)."""
    m = S.shape[1]
    s, p = z[:, :6], z[:, 6:]
    e = s - p @ S.T
    Ke = e @ K
    grad = np.concatenate([Ke, -(Ke @ S) - p @ V], axis=1)
    H = np.block([[K, -K @ S], [-(K @ S).T, S.T @ K @ S - V]]) if m else K.copy()
    return grad, H


class _Design:
    """Derivatives of the invariant basis functions at sample points, in scaled variables."""

    def __init__(self, exponents: np.ndarray, basis: np.ndarray):
        nv = exponents.shape[1]
        eye = np.eye(nv, dtype=np.int64)
        lowered = [a - eye[j] for a in exponents for j in np.flatnonzero(a)]
        self.table = Monomials(np.array(lowered, dtype=np.int64).reshape(-1, nv))
        index = self.table.index
        T = exponents.shape[0]
        self.grad_index = np.zeros((T, nv), dtype=np.int64)
        self.grad_factor = np.zeros((T, nv))
        self.hess_index = np.zeros((T, nv, nv), dtype=np.int64)
        self.hess_factor = np.zeros((T, nv, nv))
        for t, alpha in enumerate(exponents):
            for j in np.flatnonzero(alpha):
                a1 = alpha - eye[j]
                self.grad_index[t, j] = index[tuple(a1)]
                self.grad_factor[t, j] = alpha[j]
                for k in np.flatnonzero(a1):
                    self.hess_index[t, j, k] = index[tuple(a1 - eye[k])]
                    self.hess_factor[t, j, k] = alpha[j] * a1[k]
        self.basis = basis
        self.nv = nv

    def gradient(self, u: np.ndarray) -> np.ndarray:
        """(n, nv, q) ∂b_i/∂u_j."""
        mon = self.table.values(u)
        terms = mon[:, self.grad_index] * self.grad_factor            # (n, T, nv)
        return terms.transpose(0, 2, 1) @ self.basis

    def hessian(self, u: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """(n, len(rows), q) ∂²b_i/∂u_j∂u_k for the flattened (j, k) pairs ``rows``."""
        mon = self.table.values(u)
        flat_index = self.hess_index.reshape(-1, self.nv * self.nv)[:, rows]
        flat_factor = self.hess_factor.reshape(-1, self.nv * self.nv)[:, rows]
        terms = mon[:, flat_index] * flat_factor                       # (n, T, r)
        return terms.transpose(0, 2, 1) @ self.basis


@dataclass
class FitResult:
    """A least-squares fit of ψ_nl and its measured quality."""

    exponents: np.ndarray
    coefficients: np.ndarray         # on the scaled monomials
    scales: np.ndarray
    unknowns: int                    # invariant basis size
    errors: dict                     # held-out (and training) errors, see :func:`fit_errors`
    settings: dict = field(default_factory=dict)
    fold: float | None = None        # fold pressure of the map w(p) (core.energy), None: w = p


def fit_energy(samples: Samples, linear: tuple, *, degree: int, pressure_degree: int, group: list[np.ndarray],
               scales: np.ndarray, held_out: np.ndarray, hessian_weight: float = 1.0,
               fold: float | None = None) -> FitResult:
    """Least squares for ψ_nl on the training samples (``~held_out``): gradients and (weighted)
    Hessians of ψ in the scaled variables ``u = [s; w(p)] / scales``, with ψ_lin fixed.
    ``linear``: ``(K, S, V)``; ``group``: :func:`symmetry_group`; ``held_out``: boolean mask of
    samples kept out of the fit and used for its error; ``fold``: pressure of the fold map
    ``w(p)`` (core.energy) or None for ``w = p``."""
    K, S, V = linear
    m = samples.n_cavities
    nv = 6 + m
    exponents, basis = invariant_basis(nv, m, degree, pressure_degree, group, scales)
    design = _Design(exponents, basis)
    train = samples.take(~held_out)
    z = train.variables()
    g_lin, H_lin = linear_derivatives(z, K, S, V)
    g_nl, H_nl = train.full_gradient() - g_lin, train.full_hessian() - H_lin
    if fold is not None and m:                      # ψ_nl's derivatives in w(p) instead of p
        w, w1, w2 = fold_map(z[:, 6:], fold)
        z = np.concatenate([z[:, :6], w], axis=1)
        H_nl[:, 6:, 6:] -= (g_nl[:, 6:] * w2 / w1)[:, :, None] * np.eye(m)
        g_nl[:, 6:] /= w1
        H_nl[:, :, 6:] /= w1[:, None, :]
        H_nl[:, 6:, :] /= w1[:, :, None]
    u = z / scales
    # residual targets in energy units: scales_j ∂ψ/∂z_j and scales_j scales_k ∂²ψ/∂z_j∂z_k
    target_g = g_nl * scales
    upper = np.array([(j, k) for j in range(nv) for k in range(j, nv)])
    rows = upper[:, 0] * nv + upper[:, 1]
    weight_h = hessian_weight * np.where(upper[:, 0] == upper[:, 1], 1.0, math.sqrt(2.0))
    target_h = (H_nl * np.outer(scales, scales)).reshape(-1, nv * nv)[:, rows]
    A_g = design.gradient(u).reshape(-1, basis.shape[1])
    blocks, rhs = [A_g], [target_g.reshape(-1)]
    if hessian_weight > 0:
        chunk = max(1, 2_000_000 // max(1, rows.size * exponents.shape[0]))
        for lo in range(0, u.shape[0], chunk):
            A_h = design.hessian(u[lo:lo + chunk], rows) * weight_h[None, :, None]
            blocks.append(A_h.reshape(-1, basis.shape[1]))
            rhs.append((target_h[lo:lo + chunk] * weight_h).reshape(-1))
    A = np.concatenate(blocks)
    b = np.concatenate(rhs)
    norms = np.linalg.norm(A, axis=0)
    norms[norms == 0] = 1.0
    solution, *_ = np.linalg.lstsq(A / norms, b, rcond=None)
    coefficients = basis @ (solution / norms)
    keep = coefficients != 0.0
    result = FitResult(exponents=exponents[keep], coefficients=coefficients[keep], scales=np.asarray(scales, float),
                       unknowns=int(basis.shape[1]), errors={},
                       settings={"degree": degree, "pressure_degree": pressure_degree,
                                 "hessian_weight": hessian_weight, "group_order": len(group)}, fold=fold)
    return result


def evaluate_fit(result: FitResult, linear: tuple, z: np.ndarray):
    """(gradient (n, nv), Hessian (n, nv, nv)) of the fitted ψ at ``z = [s; p]``."""
    m = z.shape[1] - 6
    wide = np.full(4, 1e300)
    top = np.full(m, 1e300 if result.fold is None else result.fold * (1 - 1e-15))
    fit = EnergyFit(exponents=result.exponents, coefficients=result.coefficients, scales=result.scales,
                    range=EnergyRange(np.array([0.0, -1e300, 0.0, -1e300]), wide, np.array([0.0, -1e300, 0.0, -1e300]),
                                      wide, np.full(m, -1e300), top), fold_pressure=result.fold)
    values = EnergyModel(fit, *linear).evaluate(z[:, :6], z[:, 6:])
    grad = np.concatenate([values.gradient, values.pressure_gradient], axis=1)
    H = np.concatenate([np.concatenate([values.hessian, values.mixed_hessian], 2),
                        np.concatenate([values.mixed_hessian.mT, values.pressure_hessian], 2)], 1)
    return grad, H


def load_levels(samples: Samples, load_bounds: np.ndarray, pressure_top=None) -> tuple[np.ndarray, np.ndarray]:
    """Per sample, how far into the sampled box it lies: ``(load level, pressure level)``, the
    largest of its load's group coordinates (lateral and axial force, bending and twisting moment)
    over their bounds, and of its pressures over the top sampled ones (``pressure_top``, (m,); 0
    without). 1 on the box's boundary; the measure of :func:`error_up_to`."""
    load = np.max(np.abs(group_coordinates(samples.gradient)) / load_bounds, axis=1)
    pressure = np.zeros(samples.size)
    if samples.n_cavities and pressure_top is not None:
        top = np.asarray(pressure_top, dtype=float)
        used = top > 0
        if used.any():
            pressure = np.max(np.abs(samples.pressure[:, used]) / top[used], axis=1)
    return load, pressure


def error_up_to(by_level, load: float, pressure: float = math.inf) -> tuple[float, int] | None:
    """``(largest load error, samples counted)`` of the held-out samples ``by_level`` (rows
    ``[load level, pressure level, load error]``, :func:`fit_errors`) whose load lies within
    ``load`` and pressures within ``pressure`` of the sampled box — the fit's error over the part
    of the box a use needs — or, when none lies that low, of the lowest-lying ones (the nearest
    evidence). None without samples (or rows of another form)."""
    rows = np.asarray(by_level, dtype=float)
    if rows.ndim != 2 or rows.shape[1] != 3 or not rows.size:
        return None
    inside = (rows[:, 0] <= load) & (rows[:, 1] <= pressure)
    if not inside.any():
        height = np.maximum(rows[:, 0] - load, rows[:, 1] - pressure)
        inside = height == height.min()
    return float(rows[inside, 2].max()), int(inside.sum())


def inflation_errors(result: FitResult, linear: tuple, samples: Samples, cavity: int) -> dict:
    """Errors of the fit in the free inflation response, on ``samples`` of the path that inflates
    ``cavity`` alone (no load; :func:`designer.energy_sampling.pressure_path`), at the inflated
    ones: ``pose`` — the pose the fit puts the free segment in, Δs = −H⁻¹ (∂ψ/∂s − load), in the
    stiffness norm relative to the sampled pose (‖Δs‖_K / ‖s‖_K); ``volume`` — the volume growth
    relative to the sampled one. Unlike :func:`fit_errors`' normalisation by the whole box,
    these are relative to the response itself: what a trunk's bending angle and chamber volume
    under pressure alone inherit."""
    inflated = samples.take(samples.pressure[:, cavity] > 0)
    if not inflated.size:
        return {"samples": 0}
    K = linear[0]
    grad, H = evaluate_fit(result, linear, inflated.variables())
    step = -np.linalg.solve(H[:, :6, :6], (grad[:, :6] - inflated.gradient)[:, :, None])[:, :, 0]

    def norm(x):
        return np.sqrt(np.einsum("ni,ij,nj->n", x, K, x))

    pose = norm(step) / np.maximum(norm(inflated.strain), 1e-300)
    growth = inflated.pressure_gradient[:, cavity]
    volume = np.abs(grad[:, 6 + cavity] - growth) / np.maximum(np.abs(growth), 1e-300)
    return {"samples": int(inflated.size), "pose_max": float(pose.max()), "volume_max": float(volume.max())}


def fit_errors(result: FitResult, linear: tuple, samples: Samples, load_bounds: np.ndarray,
               volume_scale: float | None, pressure_top=None, by_level: bool = False) -> dict:
    """Errors of the fit (and of ψ_lin alone, for comparison) on ``samples``:

    * ``load``: per sample, the largest error of the four load groups (lateral force, axial
      force, bending moment, twisting moment) as a fraction of that group's bound;
    * ``volume``: volume-growth error as a fraction of ``volume_scale`` (the largest sampled
      growth);
    * ``tangent``: relative Frobenius error of ∂²ψ/∂s² in the scaled variables.

    Reported as ``{"<name>_max", "<name>_rms"}`` plus ``linear_load_max`` and ``samples``; with
    ``by_level``, also ``by_level``: per sample ``[load level, pressure level, load error]``
    (:func:`load_levels`, with ``pressure_top``), sorted by level, from which :func:`error_up_to`
    gives the error over the part of the box a scene needs."""
    K, S, V = linear
    z = samples.variables()
    grad, H = evaluate_fit(result, linear, z)
    g_lin, _ = linear_derivatives(z, K, S, V)
    scales = result.scales

    def load_error(g):
        diff = group_coordinates(g[:, :6] - samples.gradient)
        return np.max(np.abs(diff) / load_bounds, axis=1)

    load = load_error(grad)
    linear_load = load_error(g_lin)
    s6 = scales[:6]
    Hs = H[:, :6, :6] * np.outer(s6, s6)
    Hd = samples.hessian * np.outer(s6, s6)
    tangent = np.linalg.norm(Hs - Hd, axis=(1, 2)) / np.linalg.norm(Hd, axis=(1, 2))
    out = {"samples": int(samples.size),
           "load_max": float(load.max()), "load_rms": float(np.sqrt(np.mean(load ** 2))),
           "linear_load_max": float(linear_load.max()),
           "tangent_max": float(tangent.max()), "tangent_rms": float(np.sqrt(np.mean(tangent ** 2)))}
    if samples.n_cavities and volume_scale:
        volume = np.max(np.abs(grad[:, 6:] - samples.pressure_gradient), axis=1) / volume_scale
        linear_volume = np.max(np.abs(g_lin[:, 6:] - samples.pressure_gradient), axis=1) / volume_scale
        out.update(volume_max=float(volume.max()), volume_rms=float(np.sqrt(np.mean(volume ** 2))),
                   linear_volume_max=float(linear_volume.max()))
    if by_level:
        levels, pressures = load_levels(samples, load_bounds, pressure_top)
        order = np.lexsort((pressures, levels))
        out["by_level"] = [[float(f"{levels[i]:.4g}"), float(f"{pressures[i]:.4g}"), float(f"{load[i]:.4g}")]
                           for i in order]
    return out


def convexity(result: FitResult, linear: tuple, z: np.ndarray) -> float:
    """Smallest eigenvalue of ∂²ψ/∂s² relative to the linear stiffness ``K`` (of ``K^{-½} H K^{-½}``)
    over the points ``z``; 1 for ψ_lin, ≤ 0 where ψ is not convex in ``s``."""
    K = linear[0]
    _, H = evaluate_fit(result, linear, z)
    w, U = np.linalg.eigh(K)
    root = U @ np.diag(w ** -0.5) @ U.T
    return float(np.linalg.eigvalsh(root @ H[:, :6, :6] @ root).min())
