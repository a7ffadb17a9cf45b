"""How far one inverse step may move a robot: a trust region on the state.

A linearised inverse step (paper eqs. 10–13) predicts the motion ``dq(λ)`` of every frame and
of the effectors; the prediction is only as good as the linearisation, which degrades with the
size of the motion. A :class:`TrustRegion` bounds each step:

* **aim** — each point effector aims at most ``translation`` from where it is (an axis effector
  at most ``rotation``, as a chord), along the straight line to its target: far targets are
  approached through intermediate ones;
* **fraction** — the step ``(λ − λ0, dq)`` is scaled by one factor ``α ≤ 1`` so that no frame
  translates by more than ``translation`` nor turns by more than ``rotation``;
* **update** — the radii grow (×2, up to 4× their start) after a step whose quality (actual
  over predicted improvement; for a tick also how close the equilibrium lies to its prediction)
  was ≥ 0.75 and that the region cut, and shrink (×¼, down to 1/1024 of their start) after one
  of quality < 0.25.

The radii start from the robot's size: ``translation = 0.15 × length``, ``rotation = 0.25 rad``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["TrustRegion", "GOOD", "POOR"]

TRANSLATION = 0.15   # start translation radius, per unit of the robot's length
ROTATION = 0.25       # start rotation radius, rad
GROWTH, SHRINK = 2.0, 0.25
LARGEST, SMALLEST = 4.0, 1.0 / 1024.0   # radii bounds, relative to their start
GOOD, POOR = 0.75, 0.25                  # step quality that grows / shrinks the region
_THREE = np.ones(3)


@dataclass
class TrustRegion:
    """Radii of one robot's inverse steps (module docstring): ``translation`` (m) and ``rotation``
    (rad) per frame per step, and ``scale`` (their multiple of the start values)."""

    translation0: float
    rotation0: float = ROTATION
    scale: float = 1.0

    @classmethod
    def of_model(cls, model) -> "TrustRegion":
        return cls(TRANSLATION * model.length_scale)

    @property
    def translation(self) -> float:
        return self.scale * self.translation0

    @property
    def rotation(self) -> float:
        return self.scale * self.rotation0

    def aim(self, positions: np.ndarray, targets: np.ndarray, is_axis: np.ndarray) -> np.ndarray:
        """Targets (n_eff, 3) moved towards ``positions`` so that none lies farther than a
        radius (``rotation`` for axis effectors, ``translation`` for points)."""
        gap = targets - positions
        flat = gap.reshape(-1)
        if float(flat.dot(flat)) <= min(self.translation, self.rotation) ** 2:   # (every gap is shorter)
            return targets
        radius = np.where(is_axis, self.rotation, self.translation)
        distance = np.sqrt(np.add.reduce(gap * gap, 1))
        if (distance <= radius).all():
            return targets
        factor = np.minimum(1.0, radius / np.maximum(distance, 1e-300))
        return positions + factor[:, None] * gap

    def fraction(self, dq: np.ndarray) -> float:
        """The largest ``α ≤ 1`` with ``α·dq`` within the radii (``dq``: ``[dx; dφ]`` per frame)."""
        squared = np.maximum.reduce((dq * dq).reshape(-1, 3).dot(_THREE).reshape(-1, 2)).tolist()  # largest |dx|², |dφ|²
        return min(1.0, self.translation / max(math.sqrt(squared[0]), 1e-300),
                   self.rotation / max(math.sqrt(squared[1]), 1e-300))

    def update(self, quality: float, cut: bool) -> None:
        """Adapt the radii to a step of ``quality`` (actual / predicted improvement); ``cut``: the
        region shortened that step."""
        if quality >= GOOD and cut:
            self.scale = min(LARGEST, GROWTH * self.scale)
        elif quality < POOR:
            self.scale = max(SMALLEST, SHRINK * self.scale)
