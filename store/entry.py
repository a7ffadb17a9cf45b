"""The catalogue entry: a condensed intervertebral segment (docs/catalogue.md).

A segment with ``n`` cavities is one symmetric (6+n)×(6+n) compliance
``[[C, G], [Gᵀ, V]]`` that maps ``[wrench on b (in a's axes, at b's origin);
cavity pressures]`` to ``[displacement of b relative to a (translation;
rotation vector, in a's axes); cavity volume growths]`` with frame ``a`` clamped
(paper eq. 2 for the 6×6 block ``C``).

A nonlinear entry (catalogue schema v2) also carries ``energy``: its segment's energy
ψ(s, p) over end poses and pressures (:mod:`vertebra.core.energy`), whose Hessian at rest is the
inverse of this compliance.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vertebra.core.energy import EnergyFit
from vertebra.core.errors import CatalogueError
from vertebra.store.soundness import soundness_problems

SYMMETRY_TOLERANCE = 1e-8


def canonical_json(payload: Any) -> str:
    """Deterministic JSON: sorted keys, no whitespace, floats in repr form."""
    return json.dumps(payload, sort_keys=True, separators=(",", ":"), allow_nan=False)


def content_key(payload: dict) -> str:
    """Content address of an entry: SHA-256 of the canonical JSON of ``payload``.

    ``payload`` must hold everything that changes the result: family, canonical
    parameters (material included), mesh settings and the versions of the
    meshing/FE stack. 20 hex digits (80 bits) keep keys readable and collisions
    out of reach for any realistic catalogue.
    """
    return hashlib.sha256(canonical_json(payload).encode()).hexdigest()[:20]


def _array(value, name: str, shape: tuple | None = None) -> np.ndarray:
    arr = np.array(value, dtype=float)
    if shape is not None and arr.shape != shape:
        raise CatalogueError(f"entry field {name!r}: shape {arr.shape}, expected {shape}")
    if not np.all(np.isfinite(arr)):
        raise CatalogueError(f"entry field {name!r}: contains NaN or infinity")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class SegmentEntry:
    """A validated, immutable catalogue entry. Invalid entries cannot be built: besides shapes
    and finiteness, the constructor runs ``store.soundness`` (positive definite compliance,
    mass, rest pose and compliance bounds implied by the family's parameters)."""

    key: str
    name: str
    family: str
    parameters: dict
    compliance: np.ndarray                 # (6+n, 6+n), symmetric positive definite
    cavity_volumes: np.ndarray             # (n,) rest volumes, m^3
    mass: float                            # kg
    center_of_mass: np.ndarray             # (3,) in frame a, m
    rest_translation: np.ndarray = field(default_factory=lambda: np.zeros(3))   # d0, b in a
    rest_quaternion: np.ndarray = field(default_factory=lambda: np.array([1.0, 0, 0, 0]))  # R0
    mesh: dict = field(default_factory=dict)        # statistics and settings (order, size, dofs...)
    accuracy: dict = field(default_factory=dict)    # e.g. {"relative_change": 1e-3, "method": "..."}
    timings: dict = field(default_factory=dict)     # mesh_s, assemble_s, solve_s, total_s
    provenance: dict = field(default_factory=dict)  # versions, date, host
    energy: EnergyFit | None = None                 # nonlinear segments: ψ(s, p) (schema v2, core.energy)

    def __post_init__(self):
        n = np.asarray(self.cavity_volumes).reshape(-1).size
        set_ = object.__setattr__
        set_(self, "compliance", _array(self.compliance, "compliance", (6 + n, 6 + n)))
        set_(self, "cavity_volumes", _array(np.reshape(self.cavity_volumes, -1), "cavity_volumes", (n,)))
        set_(self, "center_of_mass", _array(self.center_of_mass, "center_of_mass", (3,)))
        set_(self, "rest_translation", _array(self.rest_translation, "rest_translation", (3,)))
        quaternion = _array(self.rest_quaternion, "rest_quaternion", (4,))
        if abs(np.linalg.norm(quaternion) - 1.0) > 1e-9:
            raise CatalogueError(f"entry field 'rest_quaternion': norm {np.linalg.norm(quaternion)}, expected 1")
        set_(self, "rest_quaternion", quaternion)
        if not isinstance(self.key, str) or not self.key:
            raise CatalogueError("entry field 'key': must be a non-empty string")
        if not isinstance(self.name, str) or not self.name:
            raise CatalogueError("entry field 'name': must be a non-empty string")
        if isinstance(self.mass, bool) or not isinstance(self.mass, (int, float, np.floating, np.integer)):
            raise CatalogueError(f"entry field 'mass': expected a number, got {type(self.mass).__name__}")
        if not (np.isfinite(self.mass) and self.mass >= 0.0):
            raise CatalogueError(f"entry field 'mass': {self.mass} is not a finite non-negative number")
        set_(self, "mass", float(self.mass))
        c = self.compliance
        scale = np.max(np.abs(np.diag(c)))
        asym = np.max(np.abs(c - c.T)) / scale if scale > 0 else np.inf
        if not asym <= SYMMETRY_TOLERANCE:
            raise CatalogueError(
                f"entry {self.name!r} field 'compliance': relative asymmetry {asym:.3g} > {SYMMETRY_TOLERANCE}")
        problems = soundness_problems(self)
        if problems:
            raise CatalogueError(f"entry {self.name!r} is not physically sound: " + "; ".join(problems))
        if self.energy is not None:
            if not isinstance(self.energy, EnergyFit):
                raise CatalogueError(f"entry {self.name!r} field 'energy': expected an EnergyFit, "
                                     f"got {type(self.energy).__name__}")
            if self.energy.n_cavities != n:
                raise CatalogueError(f"entry {self.name!r} field 'energy': fitted for {self.energy.n_cavities} "
                                     f"cavities, the entry has {n}")
            if np.any(quaternion != np.array([1.0, 0.0, 0.0, 0.0])):
                raise CatalogueError(f"entry {self.name!r} field 'energy': a nonlinear entry needs the identity "
                                     "rest rotation")

    @property
    def n_cavities(self) -> int:
        return self.cavity_volumes.size

    @property
    def C(self) -> np.ndarray:
        """6×6 frame compliance (paper eq. 2)."""
        return self.compliance[:6, :6]

    @property
    def G(self) -> np.ndarray:
        """6×n displacement of b per unit cavity pressure."""
        return self.compliance[:6, 6:]

    @property
    def V(self) -> np.ndarray:
        """n×n volume growth of cavity j per unit pressure in cavity k."""
        return self.compliance[6:, 6:]
