"""Where a scene takes its segments: the strain, load and pressure ranges a fitted entry must cover.

A nonlinear entry stores its energy ψ(ξ, p) fitted over a sampled range of strains and
pressures (DESIGN §2, schema v2); a scene that leaves that range extrapolates the fit. Before
such entries are designed for a scene, this module estimates, for every segment, what the scene
asks of it:

* **pressures** — exactly, from the scene: for each cavity of the segment, the bounds
  ``[min_pressure, max_pressure]`` of the chambers that act on it (``inf`` when a chamber has
  no upper bound: the fit then samples up to the inflation limit);
* **strains and loads** — by solving the scene with the *linear* entries of its segments (the
  same designs with ``material = "linear"``, cheap to design and exact at small strain) at
  every corner of its actuation box (each actuator at its lower or upper bound; an actuator
  without a finite upper bound at its forward value), at its forward actuation, always under
  its loads and gravity; then taking, per segment, the extremes over those equilibria and over
  the segment's links of the strain ``s = ξ − ξ₀`` and of the load ``w = ∂ψ/∂ξ`` in the group
  coordinates of the fitted entries (lateral ``|s_xy|``, axial ``s_z``, bending ``|φ_xy|``,
  twist ``φ_z``), and enlarging them about zero by :data:`ENLARGE`.

Why corners: with a linear response, every such coordinate is a linear function of the
actuation, whose extremes over a box are at corners; the chain of linear entries is
geometrically nonlinear, so the corners are an estimate, and the enlargement covers what lies
between. The loads ``w`` are fixed by statics (the wrench the distal part of the trunk puts on
the segment), so the linear entries estimate them well (FIELD-NOTES: tips within 0.1–3 % of
length of a full nonlinear FE trunk up to ~90° under loads). Pressure-driven strains are
underestimated by linear entries (bending 24–64 % too small at 0.5–1.4 bar for CBHA-like
slices): the fit's pressure paths, which run to the scene's pressure bounds, sample those.

With more than :data:`MAX_CORNERS` corners (``2^n`` for ``n`` free actuators), the corners
solved are all-lower, all-upper, each actuator alone at its upper bound, each alone at its
lower bound, and seeded random corners up to the limit.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from vertebra.store.errors import ConvergenceError

#: factor by which the strain and load extremes are enlarged about zero (covers the response
#: between corners and the constitutive difference of nonlinear entries under loads)
ENLARGE = 1.25
#: largest number of actuation corners solved (beyond it, a deterministic subset)
MAX_CORNERS = 64
#: the group coordinates of strains and loads, as fitted entries bound them
GROUPS = ("lateral", "axial", "bending", "twist")
_RADIAL = (0, 2)                      # groups that are norms (lower bound 0)


def group_coordinates(v: np.ndarray) -> np.ndarray:
    """(…, 4) ``[|v_xy|, v_z, |v_θxy|, v_θz]`` of (…, 6) strains or loads ``[translation; rotation]``."""
    return np.stack([np.hypot(v[..., 0], v[..., 1]), v[..., 2], np.hypot(v[..., 3], v[..., 4]), v[..., 5]], axis=-1)


@dataclass(frozen=True)
class SegmentRange:
    """What a scene asks of one segment: bounds of the group coordinates (:data:`GROUPS`) of
    its links' strain ``s = ξ − ξ₀`` and load ``w = ∂ψ/∂ξ`` (each range contains zero, the
    rest state), and per cavity the pressure bounds ``{cavity: (lower, upper)}`` of the
    chambers acting on it (cavities no chamber uses are absent: their pressure stays 0)."""

    segment: int
    strain_lower: np.ndarray          # (4,)
    strain_upper: np.ndarray          # (4,)
    load_lower: np.ndarray            # (4,)
    load_upper: np.ndarray            # (4,)
    pressures: dict

    def to_json(self) -> dict:
        return {"segment": self.segment, "groups": list(GROUPS),
                "strain": [self.strain_lower.tolist(), self.strain_upper.tolist()],
                "load": [self.load_lower.tolist(), self.load_upper.tolist()],
                "pressures": {str(c): list(bounds) for c, bounds in sorted(self.pressures.items())}}


@dataclass(frozen=True)
class RangeEstimate:
    """Per-segment ranges of a scene and how they were estimated."""

    segments: tuple                   # SegmentRange, one per scene segment
    actuations: np.ndarray            # (k, n_actuators) the actuations solved
    failed: tuple                     # indices into ``actuations`` with no equilibrium (left out)
    enlarge: float

    def to_json(self) -> dict:
        return {"enlarge": self.enlarge, "actuations": len(self.actuations), "failed": list(self.failed),
                "segments": [s.to_json() for s in self.segments]}


def actuation_corners(lower: np.ndarray, upper: np.ndarray, *, max_corners: int = MAX_CORNERS,
                      seed: int = 0) -> np.ndarray:
    """Corners of the box ``[lower, upper]`` (k, n): all of them when there are at most
    ``max_corners``, else all-lower, all-upper, each free actuator alone at its upper bound and
    alone at its lower bound, then seeded random corners up to ``max_corners`` (or fewer when
    those alone exceed it). Actuators with ``lower == upper`` are fixed."""
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    free = np.flatnonzero(upper > lower)
    if 2 ** free.size <= max_corners:
        picks = np.array(list(itertools.product((False, True), repeat=free.size)), dtype=bool).reshape(2 ** free.size, free.size)
    else:
        eye = np.eye(free.size, dtype=bool)
        picks = np.vstack([np.zeros((1, free.size), bool), np.ones((1, free.size), bool), eye, ~eye])
        rng = np.random.default_rng(seed)
        seen = {row.tobytes() for row in picks}
        extra = []
        for _ in range(100 * max_corners):          # bounded: the box has far more corners than needed
            if len(seen) >= max_corners:
                break
            row = rng.random(free.size) < 0.5
            if row.tobytes() not in seen:
                seen.add(row.tobytes())
                extra.append(row)
        if extra:
            picks = np.vstack([picks, np.array(extra)])
    corners = np.broadcast_to(lower, (picks.shape[0], lower.size)).copy()
    corners[:, free] = np.where(picks, upper[free], lower[free])
    return corners


def actuation_box(model) -> tuple[np.ndarray, np.ndarray]:
    """The box the corners span: the actuator bounds (scene lower bounds are finite), an
    unbounded upper bound replaced by the forward value (the scene names no larger value)."""
    lower, upper = (np.asarray(b, float) for b in model.actuator_bounds)
    return lower, np.where(np.isfinite(upper), upper, np.maximum(model.default_actuation, lower))


def _segment_of_link(scene) -> np.ndarray:
    return np.repeat(np.arange(len(scene.segments)), [s.count * s.elements for s in scene.segments])


def _pressures(scene) -> list[dict]:
    """Per segment, ``{cavity: (lower, upper)}`` over the chambers acting on it."""
    out = [dict() for _ in scene.segments]
    first = 1
    for i, segment in enumerate(scene.segments):
        last = first + segment.count - 1              # the vertebrae the segment's repetitions end at
        for chamber in scene.chambers:
            if chamber.first <= last and chamber.last >= first:
                low, high = out[i].get(chamber.cavity, (np.inf, -np.inf))
                out[i][chamber.cavity] = (min(low, chamber.min_pressure), max(high, chamber.max_pressure))
        first = last + 1
    return out


def _enlarged(lower: np.ndarray, upper: np.ndarray, factor: float) -> tuple[np.ndarray, np.ndarray]:
    lower, upper = np.minimum(lower, 0.0) * factor, np.maximum(upper, 0.0) * factor
    lower[list(_RADIAL)] = 0.0
    return lower, upper


def estimate_ranges(model, *, enlarge: float = ENLARGE, max_corners: int = MAX_CORNERS,
                    seed: int = 0) -> RangeEstimate:
    """The strain, load and pressure ranges a scene asks of each of its segments (module
    docstring), from its model ``model`` (a :class:`~vertebra.solver.TrunkModel`, built with
    linear entries for its design segments). Actuations without an equilibrium are left out
    and listed in ``failed``; if none has one, ConvergenceError."""
    if not enlarge >= 1.0:
        raise ValueError(f"enlarge must be >= 1, got {enlarge!r}")
    scene = model.scene
    lower, upper = actuation_box(model)
    actuations = np.vstack([model.default_actuation[None, :],
                            actuation_corners(lower, upper, max_corners=max_corners, seed=seed)])
    strains, loads, failed = [], [], []
    for k, actuation in enumerate(actuations):
        try:
            result = model.solve(actuation)
        except ConvergenceError:
            failed.append(k)
            continue
        evaluation = model.evaluate(result.state, actuation)
        strains.append(group_coordinates(evaluation.links.xi - model.link_rest))
        loads.append(group_coordinates(evaluation.w))
    if not strains:
        raise ConvergenceError(f"no equilibrium at any of the {len(actuations)} actuations of {scene.source}")
    strains, loads = np.stack(strains), np.stack(loads)          # (solved, n_links, 4)
    of = _segment_of_link(scene)
    pressures = _pressures(scene)
    segments = []
    for i in range(len(scene.segments)):
        s, w = strains[:, of == i], loads[:, of == i]
        s_low, s_high = _enlarged(s.min(axis=(0, 1)), s.max(axis=(0, 1)), enlarge)
        w_low, w_high = _enlarged(w.min(axis=(0, 1)), w.max(axis=(0, 1)), enlarge)
        segments.append(SegmentRange(i, s_low, s_high, w_low, w_high, pressures[i]))
    return RangeEstimate(tuple(segments), actuations, tuple(failed), float(enlarge))
