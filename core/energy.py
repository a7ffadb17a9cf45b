"""The fitted energy of a segment, ψ(s, p): its definition, its linear part and its evaluation kernel.

Because the vertebrae are rigid, a segment's whole response is fixed by the relative pose of
its end frames and its cavity pressures. A nonlinear catalogue entry (schema v2) stores that
response as an energy; the runtime's links evaluate it (``solver/kinds/fitted.py``), the
designer fits it (``designer/energy_fit.py``) and the catalogue stores it (``store/schema.py``).

Variables::

    s = ξ − ξ₀ ∈ R⁶,   ξ = log_SE3(T_a⁻¹ T_b) = [ρ; φ]   (translation first, as the runtime links)
    p ∈ Rⁿ                                              (cavity pressures, Pa)

with ``ξ₀ = [d₀; 0]`` the rest strain (rest translation ``d₀``, rest rotation the identity).

Form::

    ψ(s, p) = ψ_lin(s, p) + ψ_nl(s, p)
    ψ_lin   = ½ (s − S p)ᵀ K (s − S p) − ½ pᵀ V p          (:func:`linear_part`)
    ψ_nl    = Σ_α c_α u^α,   u = [s; w(p)] / scales,   every |α| ≥ 3   (w(p) = p but near a fold)

The linear part is the linear condensation ``[[C, G], [Gᵀ, V]]`` written in the strain:
``K = inv(A C Aᵀ)`` and ``S = A G`` with ``A = ∂ξ/∂δ`` at rest (:func:`rest_strain`; the log's
translation includes half the lever arm, so ``K`` is not ``inv(C)``). It is the whole energy of
a quadratic link (``solver/kinds/quadratic.py``) and the part of ψ a fit never changes: ``ψ_nl``
has no term of total degree below three in ``(s, p)``, so the Hessian of ψ at rest IS the
linear one and small-load results do not change. Derivatives: ``∂ψ/∂s`` is the generalised
force of the segment on its strain (the wrench conjugate to ``s``), ``ΔV = −∂ψ/∂p`` the cavity
volume growth relative to the rest volumes.

Pressures near an inflation limit point. A chamber that balloons has a limit point ``P`` in
pressure where its volume growth behaves like ``V_P − a√(P − p)`` (a fold): no polynomial in
``p`` follows it closely. With ``fold_pressure = P`` the pressures enter ψ_nl through
``w(p) = 2P(1 − √(1 − p/P))`` (``u = [s; w(p)] / scales``; ψ_lin keeps ``p``). In ``w`` the fold
is smooth: ``∂ψ_nl/∂w = −(ΔV − ΔV_lin)·√(1 − p/P)`` with ``√(1 − p/P) = 1 − w/2P``, and since
``w = p + p²/4P + …`` ψ_nl still has no term below degree 3 in ``p``. Without a fold ``w = p``.

Range. A fit is only trusted where it was sampled. :class:`EnergyRange` bounds four group
coordinates — lateral translation ``|ρ⊥|``, axial translation ``ρ_z``, bending ``|φ⊥|``,
twist ``φ_z`` — of both the strain ``s`` and the load ``∂ψ/∂s``, and each pressure. The
groups are invariant under rotations about the segment axis, so the test is the same for a
segment turned about its axis. The load test carries the shape of the sampled set: the
axial log coordinate of a bent soft segment moves with about the square of the bending
angle, so a box in ``s`` alone would either cut off bent states or accept stretched ones
that were never sampled; the loads a segment carries are what the sampling bounded.

The evaluation kernel :class:`EnergyModel` is what the runtime calls once per Newton
iteration for all links of one entry: a monomial table built degree by degree (one gather
and one product per degree) and three matrix products give ψ, its gradient and Hessian
for every link at once.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import NamedTuple

import numpy as np

from vertebra.core.errors import CatalogueError
from vertebra.core.lie import hat, se3_log

#: name of the stored form (the ``representation`` attribute)
REPRESENTATION = "scaled-monomials"
#: smallest total degree of a ψ_nl term: the Hessian at rest stays the linear one
MIN_DEGREE = 3
#: largest total degree accepted when reading (a fit of degree 12 in 9 variables has 2·10⁵ terms)
MAX_DEGREE = 12
MAX_TERMS = 200_000
MAX_CAVITIES = 64
#: names of the four group coordinates of a strain or a load (the range is stated in them)
GROUPS = ("lateral", "axial", "bending", "twist")
_RADIAL = (0, 2)             # groups that are norms of (x, y) pairs: lower bound 0


def _json_roundtrip(value, what: str) -> dict:
    if not isinstance(value, dict):
        raise CatalogueError(f"energy field {what!r}: must be a dict, got {type(value).__name__}")
    try:
        return json.loads(json.dumps(value, allow_nan=False))
    except (TypeError, ValueError) as error:
        raise CatalogueError(f"energy field {what!r}: not JSON data ({error})") from None


def _floats(value, what: str, shape: tuple) -> np.ndarray:
    arr = np.array(value, dtype=float)
    if arr.shape != shape:
        raise CatalogueError(f"energy field {what!r}: shape {arr.shape}, expected {shape}")
    if not np.all(np.isfinite(arr)):
        raise CatalogueError(f"energy field {what!r}: contains NaN or infinity")
    arr.setflags(write=False)
    return arr


def group_coordinates(v: np.ndarray) -> np.ndarray:
    """(…, 4) ``[|v_xy(translation)|, v_z, |v_xy(rotation)|, v_φz]`` of (…, 6) strains or loads."""
    out = np.empty(v.shape[:-1] + (4,))
    out[..., 0] = np.hypot(v[..., 0], v[..., 1])
    out[..., 1] = v[..., 2]
    out[..., 2] = np.hypot(v[..., 3], v[..., 4])
    out[..., 3] = v[..., 5]
    return out


@dataclass(frozen=True)
class EnergyRange:
    """Where a fit was sampled: bounds on the group coordinates (:data:`GROUPS`) of the strain
    ``s`` and of the load ``∂ψ/∂s``, and on each cavity pressure. ``limit_pressure``: the
    inflation limit point met while sampling (Pa; ``None`` if none was met below the sampled
    pressures); the pressure range stays below it."""

    pose_lower: np.ndarray
    pose_upper: np.ndarray
    load_lower: np.ndarray
    load_upper: np.ndarray
    pressure_lower: np.ndarray = field(default_factory=lambda: np.zeros(0))
    pressure_upper: np.ndarray = field(default_factory=lambda: np.zeros(0))
    limit_pressure: float | None = None

    def __post_init__(self):
        set_ = object.__setattr__
        for name in ("pose_lower", "pose_upper", "load_lower", "load_upper"):
            set_(self, name, _floats(getattr(self, name), f"range.{name}", (4,)))
        n = np.reshape(self.pressure_lower, -1).size
        for name in ("pressure_lower", "pressure_upper"):
            set_(self, name, _floats(np.reshape(getattr(self, name), -1), f"range.{name}", (n,)))
        for kind in ("pose", "load"):
            lower, upper = getattr(self, f"{kind}_lower"), getattr(self, f"{kind}_upper")
            if not np.all(upper > lower):
                bad = GROUPS[int(np.argmin(upper - lower))]
                raise CatalogueError(f"energy range: {kind} bounds of {bad!r} are empty ({lower}, {upper})")
            if np.any(lower[list(_RADIAL)] != 0.0):
                raise CatalogueError(f"energy range: {kind} lower bounds of the radial groups must be 0")
        if not np.all(self.pressure_upper >= self.pressure_lower):
            raise CatalogueError("energy range: a pressure upper bound is below its lower bound")
        if self.limit_pressure is not None:
            limit = float(self.limit_pressure)
            if not (math.isfinite(limit) and np.all(self.pressure_upper < limit)):
                raise CatalogueError(f"energy range: pressures reach the inflation limit point {limit}")
            set_(self, "limit_pressure", limit)

    @property
    def n_cavities(self) -> int:
        return self.pressure_lower.size

    def excess(self, s: np.ndarray, load: np.ndarray, p: np.ndarray) -> np.ndarray:
        """(n,) largest excess over the bounds, as a fraction of the bounded interval's width
        (≤ 0: inside the fitted range). Vectorised over states."""
        return self.excesses(s, load, p).max(axis=1)

    def excesses(self, s: np.ndarray, load: np.ndarray, p: np.ndarray) -> np.ndarray:
        """(n, 8 + cavities) excess of each bounded quantity (:attr:`quantities`) over its
        bounds, as a fraction of the interval's width (≤ 0: inside)."""
        lower, upper, inverse_width, _ = self._bounds
        values = self.values(s, load, p)
        values *= inverse_width
        return np.maximum(values - upper, lower - values)

    def values(self, s: np.ndarray, load: np.ndarray, p: np.ndarray) -> np.ndarray:
        """(n, 8 + cavities) the bounded quantities (:attr:`quantities`) of strains ``s`` (n, 6),
        loads ``∂ψ/∂s`` (n, 6) and pressures ``p`` (n, cavities)."""
        _, _, _, (radial, signed) = self._bounds
        both = np.concatenate([s, load], axis=1)
        values = np.empty((s.shape[0], 8 + self.n_cavities))
        np.sqrt((both * both) @ radial, out=values[:, :4])
        values[:, 4:8] = both[:, signed]
        values[:, 8:] = p
        return values

    def ratios(self, s: np.ndarray) -> np.ndarray:
        """(n, 4) each strain group's coordinate over its bound on its side (≤ 1: inside the
        group's bounds) of strains ``s`` (n, 6)."""
        ratio = np.empty((s.shape[0], 4))
        upper, lower = self._gauge_bounds
        ratio[:, 0] = np.hypot(s[:, 0], s[:, 1]) / upper[0]
        ratio[:, 2] = np.hypot(s[:, 3], s[:, 4]) / upper[2]
        for group, k in ((1, 2), (3, 5)):
            ratio[:, group] = np.where(s[:, k] >= 0.0, s[:, k] / upper[group], s[:, k] / lower[group])
        return ratio

    def gauge(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(ρ (n,), ratios (n, 4))`` of strains ``s`` (n, 6): ``ρ = 1 + |(r − 1)⁺|``, with ``r``
        the groups' :meth:`ratios` — 1 inside the strain box, above it outside, at least every
        group's ratio (so ``s/ρ`` lies inside the box), and smooth outside where groups are
        crossed together (a max of the ratios would kink where two tie)."""
        ratio = self.ratios(s)
        over = np.maximum(ratio - 1.0, 0.0)
        return 1.0 + np.sqrt(np.einsum("ij,ij->i", over, over)), ratio

    def gauge_derivatives(self, s: np.ndarray, ratio: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(∇ρ (n, 6), ∇²ρ (n, 6, 6))`` of :meth:`gauge` at strains ``s`` outside the box
        (``ratio``: their :meth:`ratios`)."""
        n = s.shape[0]
        upper, lower = self._gauge_bounds
        over = np.maximum(ratio - 1.0, 0.0)
        excess = np.sqrt(np.einsum("ij,ij->i", over, over))
        weight = over / excess[:, None]                                   # ∂ρ/∂r_g
        grads, hessian = np.zeros((n, 4, 6)), np.zeros((n, 6, 6))        # ∇r_g; Σ_g w_g ∇²r_g
        for group, pair in ((0, (0, 1)), (2, (3, 4))):
            v = s[:, pair]
            norm = np.maximum(np.hypot(v[:, 0], v[:, 1]), 1e-300)
            e = v / norm[:, None]
            grads[:, group, list(pair)] = e / upper[group]
            block = (np.eye(2) - e[:, :, None] * e[:, None, :]) * (weight[:, group] / (upper[group] * norm))[:, None,
                                                                                                            None]
            hessian[:, pair[0]:pair[1] + 1, pair[0]:pair[1] + 1] += block
        for group, k in ((1, 2), (3, 5)):
            grads[:, group, k] = np.where(s[:, k] >= 0.0, 1.0 / upper[group], 1.0 / lower[group])
        gradient = np.einsum("ng,ngi->ni", weight, grads)
        active = (over > 0.0).astype(float)
        hessian += (np.einsum("ng,ngi,ngj->nij", active, grads, grads)
                    - gradient[:, :, None] * gradient[:, None, :]) / excess[:, None, None]
        return gradient, hessian

    @cached_property
    def inner_cube(self) -> np.ndarray:
        """(6,) half-widths of a cube about rest inside the strain box (a strain with every
        ``|s_i|`` within them is inside)."""
        upper, lower = self._gauge_bounds
        signed = np.minimum(upper, -lower)
        half = 1.0 / math.sqrt(2.0)
        return np.array([upper[0] * half, upper[0] * half, signed[1], upper[2] * half, upper[2] * half, signed[3]])

    @cached_property
    def _gauge_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The strain bounds the gauge scales by: upper bounds (> 0) and lower bounds of the
        signed groups (< 0; a bound through rest is moved off it by 1e-9 of its width)."""
        width = self.pose_upper - self.pose_lower
        return np.maximum(self.pose_upper, 1e-9 * width), np.minimum(self.pose_lower, -1e-9 * width)

    @property
    def quantities(self) -> tuple[str, ...]:
        """Names of the columns of :meth:`values` and :meth:`excesses`: the group coordinates
        (:data:`GROUPS`) of the strain and of the load, then each cavity's pressure."""
        groups = [GROUPS[g] for g in _RADIAL] * 2 + [GROUPS[g] for g in (1, 3)] * 2
        kinds = ["strain", "strain", "load", "load"] * 2
        return tuple(f"{group} {kind}" for kind, group in zip(kinds, groups)) + \
            tuple(f"cavity {k} pressure" for k in range(self.n_cavities))

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) of the quantities of :meth:`values`, in their units."""
        lower, upper, inverse_width, _ = self._bounds
        return lower / inverse_width, upper / inverse_width

    @cached_property
    def _bounds(self):
        """Bounds of ``[radial groups of s and load, signed groups of s and load, pressures]``
        divided by their intervals' widths, the widths' inverses, and the maps from ``[s, load]``."""
        radial_groups, signed_groups = list(_RADIAL), [1, 3]
        lower = np.concatenate([self.pose_lower[radial_groups], self.load_lower[radial_groups],
                                self.pose_lower[signed_groups], self.load_lower[signed_groups], self.pressure_lower])
        upper = np.concatenate([self.pose_upper[radial_groups], self.load_upper[radial_groups],
                                self.pose_upper[signed_groups], self.load_upper[signed_groups], self.pressure_upper])
        inverse_width = 1.0 / np.where(upper > lower, upper - lower, 1.0)
        radial = np.zeros((12, 4))
        for column, pair in enumerate(((0, 1), (3, 4), (6, 7), (9, 10))):
            radial[list(pair), column] = 1.0
        signed = np.array([2, 5, 8, 11])
        return lower * inverse_width, upper * inverse_width, inverse_width, (radial, signed)

    def to_dict(self) -> dict:
        return {"pose_lower": self.pose_lower.tolist(), "pose_upper": self.pose_upper.tolist(),
                "load_lower": self.load_lower.tolist(), "load_upper": self.load_upper.tolist(),
                "pressure_lower": self.pressure_lower.tolist(), "pressure_upper": self.pressure_upper.tolist(),
                "limit_pressure": self.limit_pressure, "groups": list(GROUPS)}

    @classmethod
    def from_dict(cls, data: dict) -> "EnergyRange":
        if not isinstance(data, dict):
            raise CatalogueError("energy range: not a JSON object")
        names = ("pose_lower", "pose_upper", "load_lower", "load_upper", "pressure_lower", "pressure_upper")
        missing = [n for n in names + ("limit_pressure",) if n not in data]
        if missing:
            raise CatalogueError(f"energy range: field {missing[0]!r} missing")
        return cls(**{n: data[n] for n in names}, limit_pressure=data["limit_pressure"])


@dataclass(frozen=True)
class EnergyFit:
    """The fitted nonlinear part ψ_nl of a segment's energy and what it was fitted on.

    ``exponents`` (m, 6+n) non-negative integers, each row of total degree ≥ 3 (unique rows);
    ``coefficients`` (m,) in J; ``scales`` (6+n,) of the variables ``[s; w(p)]`` (m, rad, Pa);
    ``range``: where it was sampled; ``fit_error``: errors on held-out samples; ``material``:
    the constitutive model and its constants; ``sampling``: how the samples were chosen and
    solved (JSON objects); ``fold_pressure``: the pressure of the fold map ``w(p)`` (module
    docstring) or ``None``."""

    exponents: np.ndarray
    coefficients: np.ndarray
    scales: np.ndarray
    range: EnergyRange
    fit_error: dict = field(default_factory=dict)
    material: dict = field(default_factory=dict)
    sampling: dict = field(default_factory=dict)
    fold_pressure: float | None = None
    representation: str = REPRESENTATION

    def __post_init__(self):
        set_ = object.__setattr__
        if self.representation != REPRESENTATION:
            raise CatalogueError(f"energy: representation {self.representation!r} unknown "
                                 f"(this vertebra reads {REPRESENTATION!r})")
        scales = _floats(np.reshape(self.scales, -1), "scales", (np.size(self.scales),))
        nv = scales.size
        if not 6 <= nv <= 6 + MAX_CAVITIES:
            raise CatalogueError(f"energy field 'scales': {nv} variables, expected 6 + cavities")
        if not np.all(scales > 0):
            raise CatalogueError("energy field 'scales': must be positive")
        exponents = np.array(self.exponents)
        if exponents.ndim != 2 or exponents.shape[1] != nv or exponents.shape[0] > MAX_TERMS:
            raise CatalogueError(f"energy field 'exponents': shape {exponents.shape}, expected (terms ≤ "
                                 f"{MAX_TERMS}, {nv})")
        if exponents.size and (exponents.dtype.kind not in "iu" or exponents.min() < 0):
            raise CatalogueError("energy field 'exponents': must be non-negative integers")
        exponents = exponents.astype(np.int64).reshape(-1, nv)
        degree = exponents.sum(1)
        if exponents.size and (degree.min() < MIN_DEGREE or degree.max() > MAX_DEGREE):
            raise CatalogueError(f"energy field 'exponents': total degrees {degree.min()}…{degree.max()}, "
                                 f"expected {MIN_DEGREE}…{MAX_DEGREE} (no term below degree {MIN_DEGREE}: "
                                 "the Hessian at rest must be the linear one)")
        if np.unique(exponents, axis=0).shape[0] != exponents.shape[0]:
            raise CatalogueError("energy field 'exponents': repeated rows")
        exponents.setflags(write=False)
        set_(self, "exponents", exponents)
        set_(self, "scales", scales)
        set_(self, "coefficients", _floats(np.reshape(self.coefficients, -1), "coefficients",
                                           (exponents.shape[0],)))
        if not isinstance(self.range, EnergyRange):
            raise CatalogueError(f"energy field 'range': expected an EnergyRange, got {type(self.range).__name__}")
        if self.range.n_cavities != nv - 6:
            raise CatalogueError(f"energy field 'range': {self.range.n_cavities} pressure bounds for "
                                 f"{nv - 6} cavities")
        for name in ("fit_error", "material", "sampling"):
            set_(self, name, _json_roundtrip(getattr(self, name), name))
        if self.fold_pressure is not None:
            fold = float(self.fold_pressure)
            if not (nv > 6 and math.isfinite(fold) and fold > 0 and np.all(self.range.pressure_upper < fold)):
                raise CatalogueError(f"energy field 'fold_pressure': {self.fold_pressure!r} must be a finite pressure "
                                     "above the sampled pressures of a segment with cavities")
            set_(self, "fold_pressure", fold)

    def __eq__(self, other):
        return isinstance(other, EnergyFit) and self.digest() == other.digest()

    __hash__ = None

    @property
    def n_cavities(self) -> int:
        return self.scales.size - 6

    @property
    def degree(self) -> int:
        return int(self.exponents.sum(1).max()) if self.exponents.size else 0

    def attributes(self) -> dict:
        """The JSON metadata stored beside the arrays."""
        return {"representation": self.representation, "range": self.range.to_dict(),
                "fit_error": self.fit_error, "material": self.material, "sampling": self.sampling,
                "fold_pressure": self.fold_pressure}

    def digest_bytes(self) -> bytes:
        """Bytes that identify the fit, for the entry checksum: the arrays (little-endian, shapes
        prefixed) and the canonical JSON of the metadata."""
        parts = []
        for name, arr in (("exponents", np.ascontiguousarray(self.exponents, "<i8")),
                          ("coefficients", np.ascontiguousarray(self.coefficients, "<f8")),
                          ("scales", np.ascontiguousarray(self.scales, "<f8"))):
            parts.append(f"energy.{name}:{','.join(map(str, arr.shape))}:".encode() + arr.tobytes())
        parts.append(json.dumps(self.attributes(), sort_keys=True, separators=(",", ":"),
                                allow_nan=False).encode())
        return b"".join(parts)

    def digest(self) -> str:
        return hashlib.sha256(self.digest_bytes()).hexdigest()

    def to_dict(self) -> dict:
        """JSON-ready (exponents as integer lists, floats exact)."""
        return {"exponents": self.exponents.tolist(), "coefficients": self.coefficients.tolist(),
                "scales": self.scales.tolist(), **self.attributes()}

    @classmethod
    def from_dict(cls, data: dict) -> "EnergyFit":
        if not isinstance(data, dict):
            raise CatalogueError("energy: not a JSON object")
        names = ("exponents", "coefficients", "scales", "representation", "range", "fit_error", "material",
                 "sampling", "fold_pressure")
        missing = [n for n in names if n not in data]
        if missing:
            raise CatalogueError(f"energy: field {missing[0]!r} missing")
        exponents = np.array(data["exponents"], dtype=object)
        if exponents.size and not all(isinstance(v, int) and not isinstance(v, bool) for v in exponents.flat):
            raise CatalogueError("energy field 'exponents': must be integers")
        nv = len(data["scales"]) if isinstance(data["scales"], list) else 0
        return cls(exponents=np.array(data["exponents"], dtype=np.int64).reshape(-1, nv),
                   coefficients=data["coefficients"], scales=data["scales"],
                   range=EnergyRange.from_dict(data["range"]), fit_error=data["fit_error"],
                   material=data["material"], sampling=data["sampling"], fold_pressure=data["fold_pressure"],
                   representation=data["representation"])

    def check(self, compliance: np.ndarray, rest_translation: np.ndarray) -> list[str]:
        """Consistency with its entry (``verify``): problems found, [] if none. The Hessian at rest
        must be the linear one (no term below degree 3: checked on construction, and here by
        evaluation); the range must contain the rest state; the linear energy must be built."""
        problems = []
        try:
            model = EnergyModel(self, *linear_terms(compliance, rest_translation))
        except CatalogueError as error:
            return [str(error)]
        rest = model.evaluate(np.zeros((1, 6)), np.zeros((1, self.n_cavities)))
        K, S, V = model.stiffness, model.pressure_map, model.volume_compliance
        hessian = np.block([[K, -K @ S], [-(K @ S).T, S.T @ K @ S - V]])
        got = np.block([[rest.hessian[0], rest.mixed_hessian[0]],
                        [rest.mixed_hessian[0].T, rest.pressure_hessian[0]]])
        scale = np.sqrt(np.abs(np.diag(hessian)))
        scale[scale == 0] = 1.0
        if not np.max(np.abs(got - hessian) / np.outer(scale, scale)) <= 1e-12:
            problems.append("energy: the Hessian at rest differs from the linear compliance's")
        if np.any(np.abs(rest.gradient) > 0) or np.any(np.abs(rest.pressure_gradient) > 0):
            problems.append("energy: nonzero load at rest")
        if not rest.in_range[0]:
            problems.append("energy: the fitted range does not contain the rest state")
        return problems


# ------------------------------------------------------------------------ linear part

#: the identity rotation as a unit quaternion [w, x, y, z]
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def rest_strain(rest_translation: np.ndarray, rest_quaternion: np.ndarray | None = None):
    """``(ξ₀, A)`` of rest poses of ``b`` in ``a`` (translations ``d₀`` (..., 3), rotations (..., 4);
    None: the identity): the rest strain ``ξ₀ = log_SE3(T₀)`` (..., 6) and ``A = ∂ξ/∂δ`` at rest
    (..., 6, 6), the map from the displacement ``δ = [Δx; Δθ]`` of ``b`` in ``a``'s axes (the
    compliance's rows) to the strain. A left perturbation ``ζ = [Δx − Δθ × d₀; Δθ]`` moves the
    strain by ``J_l⁻¹(ξ₀) ζ``, so ``A = J_l⁻¹(ξ₀) [[I, d̂₀], [0, I]]``; at the identity rotation
    ``A = [[I, ½ d̂₀], [0, I]]`` (the log's translation carries half the lever arm)."""
    d = np.asarray(rest_translation, dtype=float)
    q = np.broadcast_to(IDENTITY, d.shape[:-1] + (4,)) if rest_quaternion is None else \
        np.asarray(rest_quaternion, dtype=float)
    rest, Jl_inv = se3_log(q, d)
    shift = np.broadcast_to(np.eye(6), d.shape[:-1] + (6, 6)).copy()
    shift[..., :3, 3:] = hat(d)
    return rest, Jl_inv @ shift


class LinearPart(NamedTuple):
    """ψ_lin of a segment (module docstring): the stiffness ``K`` (6, 6) in the strain (by block
    N/m, N/rad, N m/rad), the strain per unit pressure ``S`` (6, n) (m/Pa, rad/Pa) and the volume
    compliance ``V`` (n, n) (m³/Pa). ``K`` is NaN when ``A C Aᵀ`` is singular."""

    stiffness: np.ndarray
    pressure_map: np.ndarray
    volume_compliance: np.ndarray

    @property
    def positive(self) -> bool:
        """Is ``K`` finite with a positive diagonal?"""
        K = self.stiffness
        return bool(np.all(np.isfinite(K)) and np.all(np.diag(K) > 0))


def linear_part(C: np.ndarray, G: np.ndarray, V: np.ndarray, strain_map: np.ndarray) -> LinearPart:
    """ψ_lin from the compliance blocks ``[[C, G], [Gᵀ, V]]`` and ``A = ∂ξ/∂δ`` at rest
    (:func:`rest_strain`): ``K = inv(A C Aᵀ)`` (symmetrised), ``S = A G``, ``V``."""
    A = strain_map
    with np.errstate(all="ignore"):
        try:
            K = np.linalg.inv(A @ C @ A.T)
        except np.linalg.LinAlgError:
            K = np.full((6, 6), np.nan)
    return LinearPart(0.5 * (K + K.T), A @ G, V)


def linear_terms(compliance: np.ndarray, rest_translation: np.ndarray) -> LinearPart:
    """ψ_lin of a catalogue entry (identity rest rotation) from its compliance ``[[C, G], [Gᵀ, V]]``
    and rest translation: :func:`linear_part` at :func:`rest_strain`. CatalogueError when the
    6×6 compliance is singular."""
    compliance = np.asarray(compliance, dtype=float)
    _, A = rest_strain(rest_translation)
    part = linear_part(compliance[:6, :6], compliance[:6, 6:], compliance[6:, 6:], A)
    if not np.all(np.isfinite(part.stiffness)):
        raise CatalogueError("energy: the entry's 6×6 compliance is singular")
    return part


# ------------------------------------------------------------------------ kernel

def monomial_exponents(n_variables: int, max_degree: int, min_degree: int = 0,
                       tail: int = 0, tail_degree: int | None = None) -> np.ndarray:
    """(m, n_variables) exponents of every monomial of total degree in [min_degree, max_degree],
    ordered by degree then lexicographically (last variable fastest); with ``tail_degree``,
    monomials that involve any of the last ``tail`` variables (the pressures) have total
    degree ≤ ``tail_degree``."""
    rows = []
    for degree in range(min_degree, max_degree + 1):
        for combo in itertools.combinations_with_replacement(range(n_variables), degree):
            alpha = np.bincount(np.array(combo, dtype=np.int64), minlength=n_variables)
            if tail_degree is not None and tail and degree > tail_degree and alpha[n_variables - tail:].any():
                continue
            rows.append(alpha)
    return np.array(rows, dtype=np.int64).reshape(-1, n_variables)


@dataclass(slots=True)
class EnergyValues:
    """ψ and its derivatives at ``n`` states (one row per link). The pressure derivatives are
    None when not asked for, the range fields when the range was not checked
    (:meth:`FixedPressures.evaluate`)."""

    energy: np.ndarray                     # (n,) J
    gradient: np.ndarray                   # (n, 6) ∂ψ/∂s
    hessian: np.ndarray                    # (n, 6, 6) ∂²ψ/∂s²
    pressure_gradient: np.ndarray | None   # (n, m) ∂ψ/∂p = −ΔV
    mixed_hessian: np.ndarray | None       # (n, 6, m) ∂²ψ/∂s∂p
    pressure_hessian: np.ndarray | None    # (n, m, m) ∂²ψ/∂p²
    range_excess: np.ndarray | None        # (n,) ≤ 0 inside the fitted range (see EnergyRange.excess)
    in_range: np.ndarray | None            # (n,) bool

    @property
    def volume_growth(self) -> np.ndarray:
        """(n, m) ΔV = −∂ψ/∂p, relative to the rest volumes."""
        return -self.pressure_gradient


class EnergyModel:
    """A fit compiled for batched evaluation with its entry's linear part ``(K, S, V)``
    (:func:`linear_terms`). Build once per entry.

    Evaluation has two stages, because a trunk holds its pressures while Newton moves its
    strains. :meth:`at` fixes the pressures: at given ``p`` the fitted part is a polynomial in
    the scaled strain ``u = s / scales`` alone, ``ψ_nl = Σ_β d_β(p) u^β`` with
    ``d(p) = Σ_π c_(β,π) w(p)^π`` (so are its pressure derivatives), and the matrices that map
    the monomials of ``u`` to the gradient, the Hessian and the pressure derivatives are gathered
    from ``d`` once per distinct pressure row. :meth:`FixedPressures.evaluate` then evaluates a
    table of the monomials of degree ≤ d − 1 in ``u`` (built degree by degree: one gather and one
    product per degree, the states along the columns) and two matrix products per distinct
    pressure row; Euler's identity ``q_k(u) = u·∇q_k(u)/k`` per degree ``k`` in ``u`` gives the
    energy (the degree-d monomials are never formed). :meth:`evaluate` does both stages."""

    def __init__(self, fit: EnergyFit, stiffness: np.ndarray, pressure_map: np.ndarray,
                 volume_compliance: np.ndarray):
        n = fit.n_cavities
        self.fit = fit
        self.stiffness = _floats(stiffness, "stiffness", (6, 6))
        self.pressure_map = _floats(np.reshape(pressure_map, (6, n)), "pressure_map", (6, n))
        self.volume_compliance = _floats(np.reshape(volume_compliance, (n, n)), "volume_compliance", (n, n))
        self._compile()

    @classmethod
    def of_entry(cls, entry) -> "EnergyModel":
        if entry.energy is None:
            raise CatalogueError(f"entry {entry.name!r} has no energy (a linear entry)")
        return cls(entry.energy, *linear_terms(entry.compliance, entry.rest_translation))

    def _compile(self) -> None:
        """The strain exponents ``β``, pressure exponents ``π`` and the coefficient matrix
        ``c_(β,π)``; the monomial table in ``u`` and the gathers from ``d`` to the matrices of
        :meth:`at` (index ``len(β)`` reads a zero)."""
        fit = self.fit
        m = fit.n_cavities
        exponents = fit.exponents
        strain, of_strain = np.unique(exponents[:, :6].reshape(-1, 6), axis=0, return_inverse=True)
        if m and exponents.size:
            pressure, of_pressure = np.unique(exponents[:, 6:], axis=0, return_inverse=True)
        else:
            pressure, of_pressure = np.zeros((1, m), dtype=np.int64), np.zeros(exponents.shape[0], dtype=np.int64)
        coefficients = np.zeros((pressure.shape[0], strain.shape[0]))
        coefficients[of_pressure.reshape(-1), of_strain.reshape(-1)] = fit.coefficients
        lowered, carried = [], []
        for beta, with_pressure in zip(strain, [np.any(exponents[of_strain.reshape(-1) == b, 6:]) for b in
                                               range(strain.shape[0])]):
            lowered += [beta - np.eye(6, dtype=np.int64)[j] for j in np.flatnonzero(beta)]
            if with_pressure:
                carried.append(beta)
        units = list(np.eye(6, dtype=np.int64))                     # the linear part's monomials u_k
        table = Monomials(np.array(lowered + carried + units, dtype=np.int64).reshape(-1, 6))
        index = table.index
        size, nb = table.size, strain.shape[0]
        n_hess = int(np.sum(table.exponents.sum(1) <= max(fit.degree - 2, 0)))
        inv = 1.0 / fit.scales[:6]
        gather = np.full((6, size), nb)                 # gradient and energy rows
        gradient_factor, energy_factor = np.zeros((6, size)), np.zeros((6, size))
        hess_gather = np.full((6, 6, n_hess), nb)
        hess_factor = np.zeros((6, 6, n_hess))
        value_gather = np.full(size, nb)                # values of the pressure derivatives
        constant = nb                                   # β = 0: the energy's constant at given p
        for b, beta in enumerate(strain):
            degree = int(beta.sum())
            if tuple(beta) in index:
                value_gather[index[tuple(beta)]] = b
            if degree == 0:
                constant = b
            for j in np.flatnonzero(beta):
                b1 = beta.copy()
                b1[j] -= 1
                t = index[tuple(b1)]
                gather[j, t] = b
                gradient_factor[j, t] = beta[j] * inv[j]
                energy_factor[j, t] = beta[j] / degree
                for k in np.flatnonzero(b1):
                    b2 = b1.copy()
                    b2[k] -= 1
                    t2 = index[tuple(b2)]
                    hess_gather[j, k, t2] = b
                    hess_factor[j, k, t2] = beta[j] * b1[k] * inv[j] * inv[k]
        self._strain, self._pressure, self._coefficients = strain, pressure, coefficients
        self._pressure_degree = int(pressure.max(initial=0))
        eye = np.eye(m, dtype=np.int64)
        once = np.maximum(pressure[None] - eye[:, None], 0)          # (m, Π, m): π − e_c
        twice = np.maximum(once[:, None] - eye[None, :, None], 0)    # (m, m, Π, m): π − e_c − e_e
        self._pressure_lowered = (once, twice, pressure.T.astype(float),
                                  (pressure.T[:, None] * (pressure.T[None] - eye[:, :, None])).astype(float))
        self._table, self._n_hess = table, n_hess
        self._gather = np.concatenate([gather, gather])
        self._gather_factor = np.concatenate([gradient_factor, energy_factor])
        self._hess_gather, self._hess_factor = hess_gather.reshape(36, n_hess), hess_factor.reshape(36, n_hess)
        self._value_gather, self._constant = value_gather, constant
        self._units = np.array([index[tuple(unit)] for unit in units])
        self._inv_scales = inv[:, None]
        K, S = self.stiffness, self.pressure_map
        self._KS = K @ S
        self._pp = S.T @ K @ S - self.volume_compliance
        self._rest = self._restrict(np.zeros((1, m)))
        self._rest_pressures = {}

    @property
    def n_monomials(self) -> int:
        return self._table.size

    def _pressure_monomials(self, p: np.ndarray, order: int):
        """The pressure monomials ``w(p)^π`` (u, Π) of the rows of ``p`` (u, m) (``order`` 0), or
        the coefficient vectors of ``∂d/∂p`` (u, m, B) and, with ``order`` 2, of ``∂²d/∂p²``
        (u, m, m, B) (``fold_map``'s chain rule included)."""
        m = self.fit.n_cavities
        powers = self._pressure                                      # (Π, m)
        fold = self.fit.fold_pressure
        if m and fold is not None:
            w, w1, w2 = fold_map(p, fold)
        else:
            w, w1, w2 = p, np.ones_like(p), np.zeros_like(p)
        scale = self.fit.scales[6:]
        up = w / scale
        table = np.empty((p.shape[0], m, self._pressure_degree + 1))  # u_c^k: products, no pow()
        table[:, :, 0] = 1.0
        for k in range(1, table.shape[2]):
            np.multiply(table[:, :, k - 1], up, out=table[:, :, k])
        cavity = np.arange(m)
        monomials = np.prod(table[:, cavity, powers], axis=2)          # (u, Π)
        if order == 0:
            return monomials
        once, twice, once_factor, twice_factor = self._pressure_lowered
        first = once_factor * np.prod(table[:, cavity, once], axis=3)                  # (u, m, Π): ∂/∂u_c
        C = self._coefficients
        chain = w1 / scale                                           # ∂u_c/∂p_c
        d1 = first @ C
        if order == 1:
            return d1 * chain[:, :, None], None
        second = twice_factor * np.prod(table[:, cavity, twice], axis=4)              # (u, m, m, Π)
        d2 = (second @ C) * (chain[:, :, None] * chain[:, None, :])[..., None]
        d2 += (w2 / scale)[:, :, None, None] * np.eye(m)[None, :, :, None] * d1[:, :, None]
        return d1 * chain[:, :, None], d2

    def _restrict(self, p: np.ndarray) -> list:
        """For each row of the pressures ``p`` (u, m): the whole ψ(·, p) as a polynomial in the
        scaled strain — (strain matrix (12, T): gradient rows, then the energy's Euler rows;
        Hessian matrix (36, T_h); the energy's constant). ψ_lin is folded in: at given ``p`` it is
        ``½ sᵀKs − (KSp)·s + ½ (Sp)ᵀK(Sp) − ½ pᵀVp``, terms of degree 2, 1 and 0 in ``u``."""
        d = self._pressure_monomials(p, 0) @ self._coefficients      # (u, B)
        d = np.concatenate([d, np.zeros((d.shape[0], 1))], axis=1)   # the zero that absent entries read
        K, S, V = self.stiffness, self.pressure_map, self.volume_compliance
        scaled = K * self.fit.scales[:6]                             # K D: ∂(½ sᵀKs)/∂s on the monomials u_k
        out = []
        for row, pressures in zip(d, p):
            strain = row[self._gather] * self._gather_factor
            hess = row[self._hess_gather] * self._hess_factor
            shift = S @ pressures                                    # S p
            force = K @ shift                                        # K S p
            strain[:6, self._units] += scaled
            strain[6:, self._units] += 0.5 * self.fit.scales[:6, None] * scaled
            strain[:6, 0] -= force
            strain[6:, 0] -= force * self.fit.scales[:6]
            hess[:, 0] += K.reshape(36)
            constant = float(row[self._constant]) + 0.5 * float(shift @ force) - 0.5 * float(pressures @ V @ pressures)
            out.append((strain, hess, constant))
        return out

    def _restrict_pressures(self, p: np.ndarray, order: int) -> list:
        """For each row of the pressures ``p`` (u, m): the matrix (m + 6m, T) of the pressure
        derivatives of ψ(·, p) — ∂ψ/∂p values, ∂²ψ/∂s∂p rows (cavity-major) — and with ``order``
        2 also (m², T) of ∂²ψ/∂p² values; ψ_lin folded in (``∂ψ_lin/∂p = −SᵀK(s − Sp) − Vp``,
        ``∂²ψ_lin/∂s∂p = −KS``, ``∂²ψ_lin/∂p² = SᵀKS − V``)."""
        m = self.fit.n_cavities
        d1, d2 = self._pressure_monomials(p, order)
        d1 = np.concatenate([d1, np.zeros(d1.shape[:2] + (1,))], axis=2)
        gather, factor = self._gather[:6], self._gather_factor[:6]
        KS = self._KS
        out = []
        for g, (first, pressures) in enumerate(zip(d1, p)):
            parts = [first[:, self._value_gather], (first[:, gather] * factor).reshape(6 * m, -1)]
            if order == 2:
                second = np.concatenate([d2[g].reshape(m * m, -1), np.zeros((m * m, 1))], axis=1)
                parts.append(second[:, self._value_gather])
            matrix = np.concatenate(parts)
            matrix[:m, 0] += self._pp @ pressures
            matrix[:m, self._units] -= KS.T * self.fit.scales[:6]
            matrix[m:7 * m, 0] -= KS.T.reshape(6 * m)
            if order == 2:
                matrix[7 * m:, 0] += self._pp.reshape(m * m)
            out.append(matrix)
        return out

    def at(self, p: np.ndarray | None = None) -> "FixedPressures":
        """The energy at the cavity pressures ``p`` (n, m) (None: all zero), ready to evaluate
        at strains of the same ``n`` rows."""
        m = self.fit.n_cavities
        if p is None or not m:
            return FixedPressures(self, None, np.zeros((1, m)), None, self._rest)
        p = np.asarray(p, dtype=float).reshape(-1, m)
        if not np.any(p):
            return FixedPressures(self, p, np.zeros((1, m)), None, self._rest)
        rows = np.ascontiguousarray(p).view(np.dtype((np.void, 8 * m))).reshape(-1)    # a row as one key
        _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
        distinct = p[first]
        groups = None if first.size == 1 else [np.flatnonzero(inverse == g) for g in range(first.size)]
        return FixedPressures(self, p, distinct, groups, self._restrict(distinct))

    def evaluate(self, s: np.ndarray, p: np.ndarray | None = None) -> EnergyValues:
        """ψ and all its derivatives, and the range test, at the strains ``s`` (n, 6) and
        pressures ``p`` (n, m)."""
        return self.at(p).evaluate(s)


class FixedPressures:
    """An :class:`EnergyModel` at fixed cavity pressures (see :meth:`EnergyModel.at`): the rows
    with the same pressures (``distinct``) share one restricted polynomial (``groups``: their row
    indices, or None when every row has the first). The matrices of the pressure derivatives are
    gathered when first asked for; the last evaluation with the range test is kept (a
    linearisation asks for the chamber forces, the volume growth and the range at one state)."""

    def __init__(self, model: EnergyModel, p: np.ndarray | None, distinct: np.ndarray, groups: list | None,
                 restricted: list):
        self.model, self.p, self.distinct, self.groups, self.restricted = model, p, distinct, groups, restricted
        self._pressures = {}
        self._last = (None, -1, None)

    def _pressure_matrices(self, order: int) -> list:
        model = self.model
        cache = model._rest_pressures if self.restricted is model._rest else self._pressures   # zero p: a constant
        if 2 in cache:
            return cache[2]
        if order not in cache:
            cache[order] = model._restrict_pressures(self.distinct, order)
        return cache[order]

    def evaluate(self, s: np.ndarray, *, derivatives: int = 2, check_range: bool = True,
                 extend: bool = True) -> EnergyValues:
        """ψ, ``∂ψ/∂s`` and ``∂²ψ/∂s²`` at the strains ``s`` (n, 6); with ``derivatives`` 1 also
        ``∂ψ/∂p`` and ``∂²ψ/∂s∂p``, with 2 also ``∂²ψ/∂p²``; with ``check_range`` the range test.
        Strains outside the range's strain box take the tail of :meth:`_extend` (``extend``
        False: the polynomial everywhere, for tests of the polynomial itself)."""
        s = np.asarray(s, dtype=float)
        kept, order, values = self._last
        if check_range and extend and order >= derivatives and np.array_equal(kept, s):
            return values
        values = self._evaluate(s, derivatives, check_range, extend)
        if check_range and extend:
            self._last = (s.copy(), derivatives, values)
        return values

    def _evaluate(self, s: np.ndarray, derivatives: int, check_range: bool, extend: bool) -> EnergyValues:
        model = self.model
        n, m = s.shape[0], model.fit.n_cavities
        energy, grad, hess, extra, _, _ = self._polynomial(s, derivatives)
        if extend:
            self._extend(s, derivatives, energy, grad, hess, extra)
        pressure_gradient = mixed = pressure_hessian = None
        if extra is not None:
            pressure_gradient = extra[:, :m]
            mixed = extra[:, m:7 * m].reshape(n, m, 6).transpose(0, 2, 1)
            if derivatives == 2:
                pressure_hessian = extra[:, 7 * m:].reshape(n, m, m)
        p = np.zeros((n, m)) if self.p is None else self.p
        excess = model.fit.range.excess(s, grad, p) if check_range else None
        return EnergyValues(energy=energy, gradient=grad, hessian=hess, pressure_gradient=pressure_gradient,
                            mixed_hessian=mixed, pressure_hessian=pressure_hessian, range_excess=excess,
                            in_range=None if excess is None else excess <= 0.0)

    def _positions(self, rows: np.ndarray | None) -> list:
        """For each restricted polynomial, the positions among ``rows`` (None: all rows) of the
        rows it serves."""
        if self.groups is None:
            return [slice(None)]
        if rows is None:
            return self.groups
        of_row = np.empty(sum(g.size for g in self.groups), dtype=np.int64)
        for g, members in enumerate(self.groups):
            of_row[members] = g
        of = of_row[rows]
        return [np.flatnonzero(of == g) for g in range(len(self.groups))]

    def _polynomial(self, s: np.ndarray, derivatives: int, rows: np.ndarray | None = None, along: bool = False):
        """``(ψ, ∂ψ/∂s, ∂²ψ/∂s², pressure derivatives, d_hessian, d_pressure)`` of the polynomial at
        strains ``s`` (k, 6) of the rows ``rows`` (None: every row, in order); the pressure
        derivatives (k, 7m [+ m²]) as :meth:`_evaluate` unpacks them, or None. With ``along`` also
        ``d/dt`` at ``t = 1`` of the Hessian and of the pressure derivatives at ``t·s`` — exact:
        a monomial of degree ``j`` in ``u`` scales by ``t^j``, so the derivative weights it by ``j``."""
        model = self.model
        n, m = s.shape[0], model.fit.n_cavities
        u = np.ascontiguousarray(s.T) * model._inv_scales                # (6, n)
        energy, grad, hess = np.empty(n), np.empty((n, 6)), np.empty((n, 6, 6))
        width = 7 * m + (m * m if derivatives == 2 else 0)
        extra = np.empty((n, width)) if derivatives else None
        d_hess = np.empty((n, 6, 6)) if along else None
        d_extra = np.empty((n, width)) if along and derivatives else None
        matrices = self._pressure_matrices(derivatives) if derivatives and m else [None] * len(self.restricted)
        degrees = model._table.degrees
        for row, (strain, hessian, constant), pressure in zip(self._positions(rows), self.restricted, matrices):
            ug = u[:, row]
            if not ug.shape[1]:
                continue
            mon = model._table.values_t(ug)
            both = strain @ mon                                          # (12, k)
            grad[row] = both[:6].T
            energy[row] = constant + (ug * both[6:]).sum(0)
            hess[row] = (hessian @ mon[:model._n_hess]).T.reshape(-1, 6, 6)
            if pressure is not None:
                extra[row] = (pressure[:width] @ mon).T
            if along:
                weighted = mon * degrees[:, None]
                d_hess[row] = (hessian @ weighted[:model._n_hess]).T.reshape(-1, 6, 6)
                if pressure is not None:
                    d_extra[row] = (pressure[:width] @ weighted).T
        if derivatives and not m:
            extra[:] = 0.0
            if along:
                d_extra[:] = 0.0
        return energy, grad, hess, extra, d_hess, d_extra

    def _extend(self, s: np.ndarray, derivatives: int, energy: np.ndarray, grad: np.ndarray, hess: np.ndarray,
                extra: np.ndarray | None) -> None:
        """ψ beyond the strain box, in place on the rows whose strain lies outside it.

        With ``ρ`` the box's gauge (:meth:`EnergyRange.gauge`) and ``ŝ = s/ρ`` the boundary point
        on the ray from rest, ψ_nl continues along the ray with its boundary slope::

            ψ(s) = ψ_lin(s) + ψ_nl(ŝ) + (ρ − 1) ∇ψ_nl(ŝ)·ŝ

        so the fitted correction's force stays bounded (``∂ψ_nl/∂s = g + (1 − 1/ρ)(I − ∇ρ ŝᵀ) H ŝ``
        with ``g, H`` its gradient and Hessian at ŝ) and the linear entry's quadratic carries
        the rest: ψ is C¹ across the boundary, and its curvature tends to the linear entry's
        (the tail's own is ``O(1/ρ)``). The Hessian is exact where one group sets the gauge: the
        third derivatives it needs enter only as ``d/dt H(tŝ)``, which the degree-weighted
        monomials give exactly (:meth:`_polynomial`); the pressure derivatives likewise."""
        model = self.model
        fitted = model.fit.range
        if np.all(np.abs(s) <= fitted.inner_cube):          # inside for sure: the common case, cheaply
            return
        rho, ratio = fitted.gauge(s)
        out = np.flatnonzero(rho > 1.0)
        if not out.size:
            return
        m = model.fit.n_cavities
        so, r = s[out], rho[out]
        hat = so / r[:, None]
        e, g, H, x, dH, dx = self._polynomial(hat, derivatives, rows=out, along=True)
        K, S, V = model.stiffness, model.pressure_map, model.volume_compliance
        p = np.zeros((out.size, m)) if self.p is None else self.p[out]
        shift = p @ S.T                                                  # S p
        lin_g, lin_gh = (so - shift) @ K, (hat - shift) @ K              # ∇ψ_lin at s and at ŝ
        pressure_energy = 0.5 * np.einsum("ki,ki->k", p @ V, p)
        lin_e = 0.5 * np.einsum("ki,ki->k", so - shift, lin_g) - pressure_energy
        lin_eh = 0.5 * np.einsum("ki,ki->k", hat - shift, lin_gh) - pressure_energy
        g_nl, H_nl = g - lin_gh, H - K
        w = np.einsum("kij,kj->ki", H_nl, hat)                           # H_nl ŝ = d/dt ∇ψ_nl(tŝ)
        along = np.einsum("ki,ki->k", hat, w)
        grad_rho, hess_rho = fitted.gauge_derivatives(so, ratio[out])
        c, t = 1.0 - 1.0 / r, r - 1.0
        Pw = w - grad_rho * along[:, None]                               # (I − ∇ρ ŝᵀ) H_nl ŝ
        energy[out] = lin_e + (e - lin_eh) + t * np.einsum("ki,ki->k", g_nl, hat)
        grad[out] = lin_g + g_nl + c[:, None] * Pw
        eye = np.eye(6)
        J = (eye - hat[:, :, None] * grad_rho[:, None, :]) / r[:, None, None]    # ∂ŝ/∂s
        P = eye - grad_rho[:, :, None] * hat[:, None, :]
        Jw = np.einsum("kji,kj->ki", J, w)
        curvature = (-hess_rho * along[:, None, None] - grad_rho[:, :, None] * Jw[:, None, :]
                     + P @ (dH + H_nl) @ J)
        full = K + H_nl @ J + Pw[:, :, None] * (grad_rho / (r * r)[:, None])[:, None, :] + c[:, None, None] * curvature
        hess[out] = 0.5 * (full + full.transpose(0, 2, 1))
        if extra is None or not m:
            return
        pg, mixed, dmixed = x[:, :m], x[:, m:7 * m].reshape(-1, m, 6), dx[:, m:7 * m].reshape(-1, m, 6)
        mixed_nl = mixed + (K @ S).T[None]                               # cavity-major, as stored
        extra[out, :m] = pg - (lin_g - lin_gh) @ S + t[:, None] * np.einsum("kci,ki->kc", mixed_nl, hat)
        extra[out, m:7 * m] = (mixed + c[:, None, None] * np.einsum("kij,kcj->kci", P, dmixed)).reshape(-1, 6 * m)
        if derivatives == 2:
            extra[out, 7 * m:] = x[:, 7 * m:] + t[:, None] * dx[:, 7 * m:]


def fold_map(p: np.ndarray, fold: float):
    """``w(p) = 2P(1 − √(1 − p/P))`` and its first two derivatives (pressures below ``P``)."""
    root = np.sqrt(1.0 - p / fold)
    return 2.0 * fold * (1.0 - root), 1.0 / root, 0.5 / (fold * root ** 3)


class Monomials:
    """The monomials dividing a set of exponents (constant included), ordered by degree, with
    the tree that evaluates them: each monomial of degree k is a parent of degree k − 1 times
    one variable, so :meth:`values` costs one gather and one product per degree."""

    def __init__(self, exponents: np.ndarray):
        exponents = np.asarray(exponents, dtype=np.int64)
        nv = exponents.shape[1]
        seen = {tuple([0] * nv)}
        frontier = {tuple(int(v) for v in row) for row in exponents}
        while frontier:
            seen |= frontier
            below = set()
            for alpha in frontier:
                for j, a in enumerate(alpha):
                    if a:
                        beta = alpha[:j] + (a - 1,) + alpha[j + 1:]
                        if beta not in seen:
                            below.add(beta)
            frontier = below
        closure = np.array(sorted(seen), dtype=np.int64).reshape(-1, nv)
        closure = closure[np.lexsort(tuple(closure[:, ::-1].T) + (closure.sum(1),))]
        total = closure.sum(1)
        self.exponents = closure
        self.degrees = total.astype(float)
        self.index = {tuple(row): i for i, row in enumerate(closure.tolist())}
        self.blocks = []
        for k in range(1, int(total.max(initial=0)) + 1):
            rows = np.flatnonzero(total == k)
            last = nv - 1 - np.argmax(closure[rows, ::-1] > 0, axis=1)      # highest variable present
            parents = closure[rows].copy()
            parents[np.arange(rows.size), last] -= 1
            self.blocks.append((int(rows[0]), int(rows[-1]) + 1,
                                np.array([self.index[tuple(r)] for r in parents.tolist()]), last))

    @property
    def size(self) -> int:
        return self.exponents.shape[0]

    def values(self, u: np.ndarray) -> np.ndarray:
        """(n, size) values of the monomials at the points ``u`` (n, variables)."""
        return self.values_t(np.asarray(u, dtype=float).T).T

    def values_t(self, u_t: np.ndarray) -> np.ndarray:
        """(size, n) values of the monomials at the points ``u_t`` (variables, n): one point per column."""
        u_t = np.ascontiguousarray(u_t)
        mon = np.empty((self.size, u_t.shape[1]))
        mon[0] = 1.0
        for lo, hi, parents, variables in self.blocks:
            np.multiply(np.take(mon, parents, axis=0), np.take(u_t, variables, axis=0), out=mon[lo:hi])
        return mon
