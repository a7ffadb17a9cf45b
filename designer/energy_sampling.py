"""Sample a segment's nonlinear response over end poses and pressures (for :mod:`designer.energy_fit`).

What is sampled. A segment in a trunk carries a load (the generalised force ``∂ψ/∂s``
conjugate to its strain ``s``) and its cavity pressures; the fit must hold where trunks
go. The samples therefore follow *loading paths*: rays from rest to the boundary of a
box of loads and pressures, each followed by continuation — at each step the pose that
carries the step's load is predicted by one Newton step with the last tangent, the FE
solves the segment at that pose (starting from the last step's solution), and what it
returns (load, tangent, volume growths and their derivatives) is one sample. Every FE
solve is a sample; the poses stay close to the equilibrium path without being on it.

The load box (:class:`LoadBox`) comes from the family's size and material through the
linear response: the bending moment that bends the segment by ``min(bending, strain·L/r)``
(``r`` its outer radius, so the outer fibre strain stays ≤ ``strain``), the twisting moment
for ``min(twist, strain·L/r)``, the lateral force for a lateral displacement ``shear·L``, the
axial force for ``axial·L``; pressures up to ``limit_fraction`` of the inflation limit point
(found by a pressure ramp on one cavity with the top frame free, :func:`pressure_limit`) or
the requested pressure, whichever is lower. Paths: the axes of the box (pure loads, one
cavity, all cavities) and scrambled-Halton directions; every ``held_out``-th of the latter
is kept out of the fit to measure its error.

Where it runs. Paths are grouped into tasks run by the sweep executors
(:mod:`designer.executors`: ``serial``, ``local`` process pool, ``dask``); each worker
builds the segment's nonlinear FE once (:func:`worker_model`) and solves all the poses of
its tasks.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from typing import Any, Protocol

import numpy as np

from vertebra.designer.energy_fit import Samples, strain_derivatives, pose_of_strain
from vertebra.designer.executors import worker_info
from vertebra.core.energy import group_coordinates
from vertebra.core.errors import ConvergenceError, OptionError


#: environment variable: set to 1 by ``vertebra prepare`` (with its progress bar on) so that the
#: worker designing a nonlinear entry reports the stages inside it on stderr (it inherits it)
ENTRY_PROGRESS = "VERTEBRA_ENTRY_PROGRESS"


def entry_progress(label: str, material: str):
    """The ``progress`` callback of a design run in a worker: None for a linear entry or when
    :data:`ENTRY_PROGRESS` is not ``1``, else one line ``label: message`` on stderr per stage
    (pressure ramp, paths sampled so far with FE solves and seconds, the fit's held-out errors
    against the linear entry's)."""
    import os
    import sys

    if material == "linear" or os.environ.get(ENTRY_PROGRESS) != "1":
        return None

    def say(message: str) -> None:
        print(f"{label}: {message}", file=sys.stderr, flush=True)

    return say


class PoseSolver(Protocol):
    """A segment's nonlinear FE with the bottom frame clamped and the top frame at a prescribed
    pose (``x = t + R X`` on the top face) and cavity pressures."""

    n_cavities: int

    def solve(self, R, t, pressures=None, initial=None, min_load_step=None) -> Any:
        """Equilibrium at the pose: an object with ``wrench`` (6,) ``∂ψ/∂ζ`` for a left
        perturbation ``exp(ζ^)T_b`` in a's axes, ``tangent`` (6, 6), ``volumes`` (n,) cavity
        volumes (``−∂ψ/∂p`` up to the rest volumes), ``dvolume_dpose`` (n, 6),
        ``dvolume_dpressure`` (n, n) and ``state`` (to continue from). Raises
        ConvergenceError when it cannot (at once when its load steps would be cut below
        ``min_load_step``, a fraction of the way from ``initial``)."""


class ModelSpec(Protocol):
    """Picklable description of a :class:`PoseSolver` that a worker builds once."""

    def key(self) -> str: ...

    def build(self) -> PoseSolver: ...


_MODELS: dict[str, PoseSolver] = {}


def worker_model(spec: ModelSpec) -> PoseSolver:
    """The model of ``spec``, built once per process and reused by every task it runs."""
    key = spec.key()
    if key not in _MODELS:
        _MODELS.clear()                      # one segment per worker at a time
        _MODELS[key] = spec.build()
    return _MODELS[key]


#: Default outer-fibre strain sampled (``STRAIN``), lower for materials that soften in
#: compression (``SOFTENING_STRAIN``). St Venant–Kirchhoff's uniaxial stress
#: ``E/2 λ(λ² − 1)`` has a limit point in compression at the stretch ``1/√3`` (strain −0.42) and
#: softens long before it: sampled to outer-fibre strains of 0.4, a squat rod's energy fitted
#: with a held-out load error of 12.6 % and tangent error of 40 % (a 6-segment trunk 0.29 % of its
#: length off at 34°, inside the range); to 0.25, 1.6 % and 5 % (0.045 %). Neo-Hooke stiffens in
#: compression and fits to 0.4.
STRAIN = 0.4
SOFTENING_STRAIN = {"svk": 0.25}


#: the largest counts a sampling may ask for (each path is a chain of nonlinear FE solves: the
#: defaults are 18-30 paths of 6-10 steps)
SAMPLING_LIMITS = {"paths": 1000, "steps": 100, "held_out": 1000, "check_paths": 1000}


@dataclass(frozen=True)
class SamplingSettings:
    """How a nonlinear entry is sampled and fitted (all part of its content key)."""

    degree: int = 6                  # total degree of ψ in (s, p)
    pressure_degree: int | None = None   # total degree of the terms that involve a pressure (None: degree)
    fold: bool = True                # pressures through the fold map w(p) at the limit point found
    paths: int | None = None         # scrambled-Halton loading paths besides the box axes (None: 18, 30 with cavities)
    steps: int | None = None         # samples per path (None: 6, 10 with cavities)
    held_out: int = 4                # every held_out-th Halton path is held out of the fit
    bending: float = 1.3             # rad, largest bending angle sampled (75°)
    twist: float = 0.6               # rad, largest twist sampled
    strain: float | None = None      # outer-fibre strain bounding bending and twist (·L/r; None: by material)
    shear: float = 0.25              # lateral displacement of the strain chart / length
    axial: float = 0.1               # axial stretch and compression / length
    pressure: float | None = None    # Pa, largest pressure (None: up to the limit point)
    limit_fraction: float = 0.9      # pressures stay below this fraction of the inflation limit
    hessian_weight: float = 0.3      # weight of the tangent rows in the least squares
    seed: int = 0
    cavities: tuple | None = None    # cavities sampled under pressure (None: all; (): none, see pressurised)
    nonlinear_mesh_size: float | None = None   # m, coarser mesh the nonlinear part is sampled on (None: the entry's)
    check_paths: int = 2             # with nonlinear_mesh_size: held-out paths solved on the entry's mesh
    auto_nonlinear_mesh: bool = True     # above designer.multifidelity.AUTO_DOFS: choose nonlinear_mesh_size
    nonlinear_mesh_chosen: bool = False  # nonlinear_mesh_size set by that choice (falls back on a failed check)
    check_tolerance: float | None = None  # held-out error the entry-mesh check must meet (None: the default rule)

    def __post_init__(self):
        for name, limit in SAMPLING_LIMITS.items():     # counts that size the sampling's arrays
            value = getattr(self, name)
            if isinstance(value, int) and not isinstance(value, bool) and value > limit:
                raise OptionError(f"at most {limit:,}; got {value:,}", field=f"sampling.{name}")
        numbers = [name for name in ("bending", "twist", "strain", "shear", "axial", "pressure", "limit_fraction",
                                     "hessian_weight", "nonlinear_mesh_size", "check_tolerance")
                   if getattr(self, name) is not None]
        for name in numbers:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise OptionError(f"expected a finite number, got {value!r}", field=f"sampling.{name}")
        checks = {
            "degree": isinstance(self.degree, int) and 3 <= self.degree <= 10,
            "pressure_degree": self.pressure_degree is None or (isinstance(self.pressure_degree, int)
                                                                and 0 <= self.pressure_degree <= self.degree),
            "fold": isinstance(self.fold, bool),
            "paths": self.paths is None or (isinstance(self.paths, int) and self.paths >= 0),
            "steps": self.steps is None or (isinstance(self.steps, int) and self.steps >= 1),
            "held_out": isinstance(self.held_out, int) and self.held_out >= 2,
            "bending": 0 < self.bending < math.pi,
            "twist": 0 < self.twist < math.pi,
            "strain": self.strain is None or self.strain > 0,
            "shear": self.shear > 0,
            "axial": 0 < self.axial < 1,
            "pressure": self.pressure is None or self.pressure > 0,
            "limit_fraction": 0 < self.limit_fraction < 1,
            "hessian_weight": self.hessian_weight >= 0,
            "seed": isinstance(self.seed, int) and 0 <= self.seed < 2**63,
            "cavities": self.cavities is None or (isinstance(self.cavities, tuple) and all(
                isinstance(c, int) and not isinstance(c, bool) and c >= 0 for c in self.cavities)
                and len(set(self.cavities)) == len(self.cavities)),
            "nonlinear_mesh_size": self.nonlinear_mesh_size is None or self.nonlinear_mesh_size > 0,
            "check_paths": isinstance(self.check_paths, int) and not isinstance(self.check_paths, bool)
            and self.check_paths >= 1,
            "auto_nonlinear_mesh": isinstance(self.auto_nonlinear_mesh, bool),
            "nonlinear_mesh_chosen": isinstance(self.nonlinear_mesh_chosen, bool)
            and (not self.nonlinear_mesh_chosen or self.nonlinear_mesh_size is not None),
            "check_tolerance": self.check_tolerance is None or self.check_tolerance > 0,
        }
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            raise OptionError(f"{getattr(self, bad[0])!r} is out of range", field=f"sampling.{bad[0]}")

    def describe(self) -> dict:
        """The settings as JSON (``cavities`` only when set, ``nonlinear_mesh_size`` and
        ``check_paths`` only with a nonlinear mesh, ``nonlinear_mesh_chosen`` only when the
        automatic choice set it, ``check_tolerance`` only when given: the keys of the entries
        without them are those of the settings before they existed). ``auto_nonlinear_mesh`` is
        a policy, not a setting of the entry: what it chooses is described."""
        out = asdict(self)
        del out["auto_nonlinear_mesh"]
        if self.cavities is None:
            del out["cavities"]
        else:
            out["cavities"] = list(self.cavities)
        if self.nonlinear_mesh_size is None:
            del out["nonlinear_mesh_size"], out["check_paths"]
        if not self.nonlinear_mesh_chosen:
            del out["nonlinear_mesh_chosen"]
        if self.check_tolerance is None or self.nonlinear_mesh_size is None:
            del out["check_tolerance"]
        return out

    def pressurised(self, n_cavities: int) -> tuple[int, ...]:
        """The cavities sampled under pressure: ``cavities`` (checked against ``n_cavities``), or
        every one. With none, the entry is sampled and fitted at zero pressure (no inflation-limit
        search, no pressure terms; its range admits no pressure) — for a segment whose chambers no
        scene pressurises (``vertebra prepare`` knows; ``vertebra design --pressurised``)."""
        if self.cavities is None:
            return tuple(range(n_cavities))
        bad = [c for c in self.cavities if c >= n_cavities]
        if bad:
            raise OptionError(f"cavity {bad[0]} does not exist (the segment has {n_cavities})",
                              field="sampling.cavities")
        return tuple(sorted(self.cavities))

    def resolved(self, n_cavities: int, material: str) -> "SamplingSettings":
        """The settings with their automatic values filled for a segment with ``n_cavities`` of
        ``material``: a ballooning chamber needs more paths, more samples per path and the full
        degree in the pressures (measured on CBHA-like slices: pressure degree 4 left the volume
        growth 4-13 % off, 6 within 1 %; four slices at 1.5 bar, 94 % of their inflation limit,
        6 samples per path put the tip 0.41 % of the trunk length off, the bending angle 2.3 %
        and the volume growth 1.4 %, 10 samples 0.17 %, 0.9 % and 1.0 %, 14 samples no better);
        the outer-fibre strain is :data:`STRAIN`, or the material's :data:`SOFTENING_STRAIN`;
        ``cavities`` naming every cavity is the default (None: same entry, same key)."""
        from dataclasses import replace

        pressurised = self.pressurised(n_cavities)                      # checked against the segment
        cavities = None if len(pressurised) == n_cavities else pressurised
        return replace(self, cavities=cavities,
                       paths=self.paths if self.paths is not None else (30 if n_cavities else 18),
                       steps=self.steps if self.steps is not None else (10 if n_cavities else 6),
                       pressure_degree=self.pressure_degree if self.pressure_degree is not None else self.degree,
                       strain=self.strain if self.strain is not None else SOFTENING_STRAIN.get(material, STRAIN))

    @classmethod
    def from_dict(cls, data: dict | None) -> "SamplingSettings":
        data = dict(data or {})
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(data) - known)
        if unknown:
            raise OptionError(f"unknown setting (known: {', '.join(sorted(known))})", field=f"sampling.{unknown[0]}")
        if isinstance(data.get("cavities"), list):
            data["cavities"] = tuple(data["cavities"])
        return cls(**data)


@dataclass(frozen=True)
class LoadBox:
    """Bounds of the loads ``∂ψ/∂s`` by group (lateral and axial force, bending and twisting
    moment, in the strain chart's units) and of the pressures; ``normalised`` maps a load
    and pressure to the unit box, ``loads`` back."""

    lateral: float
    axial: float
    bending: float
    twist: float
    pressure: float = 0.0

    def group_bounds(self) -> np.ndarray:
        return np.array([self.lateral, self.axial, self.bending, self.twist])

    def loads(self, unit: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
        """``(load (6,), pressures (m,))`` of a point of the unit box ``[ℓ (6); p/pressure (m)]``."""
        scale = np.array([self.lateral, self.lateral, self.axial, self.bending, self.bending, self.twist])
        return unit[:6] * scale, unit[6:6 + m] * self.pressure


def load_box(K: np.ndarray, length: float, radius: float, settings: SamplingSettings,
             pressure: float = 0.0, free_pose=(0.0, 0.0, 0.0, 0.0)) -> tuple[LoadBox, np.ndarray]:
    """The load box and the pose caps ``[lateral, axial, bending, twist]`` from the linear
    stiffness ``K`` of the strain chart. Moments: those that bend and twist the segment,
    linearly, by the angle caps. Forces: a tip force on a single segment bends it about its
    middle with a lever of ``L/2``, so the lateral bound is ``2 M_bending / L`` — unless that
    displaces the segment laterally by more than ``shear·L``; the axial bound is the lateral
    one unless it stretches by more than ``axial·L``. The pose caps add the free pose the
    pressures alone produce (``free_pose``, group coordinates): a pressurised chamber bends."""
    compliance = np.diag(np.linalg.inv(K))
    bending = min(settings.bending, settings.strain * length / radius)
    twist = min(settings.twist, settings.strain * length / radius)
    moment = bending / compliance[3]
    lateral = min(2.0 * moment / length, settings.shear * length / compliance[0])
    axial = min(lateral, settings.axial * length / compliance[2])
    caps = np.array([lateral * compliance[0], axial * compliance[2], bending, twist])
    box = LoadBox(lateral=lateral, axial=axial, bending=moment, twist=twist / compliance[5], pressure=pressure)
    return box, caps + np.abs(np.asarray(free_pose, dtype=float))


#: the load-box axes every sampling follows first: (load coordinate, sign) — lateral force,
#: tension, compression, bending, twist; then (:func:`path_endpoints`) one pressurised cavity
#: alone and all of them
AXES = ((0, 1.0), (2, 1.0), (2, -1.0), (3, 1.0), (5, 1.0))


def pressure_path(n_cavities: int, settings: SamplingSettings) -> int | None:
    """The index in :func:`path_endpoints` of the path that inflates the first pressurised
    cavity alone, the segment otherwise free (None without a pressurised cavity)."""
    return len(AXES) if settings.pressurised(n_cavities) else None


def path_endpoints(n_cavities: int, settings: SamplingSettings) -> tuple[np.ndarray, np.ndarray]:
    """``(endpoints (P, 6+m) on the unit box's boundary, held_out (P,) bool)``: the box axes (pure
    lateral force, tension, compression, bending, twist; one cavity, all cavities), then
    ``settings.paths`` scrambled-Halton directions (one group at its bound). Only the
    pressurised cavities (:meth:`SamplingSettings.pressurised`) see a pressure."""
    from scipy.stats import qmc

    m = n_cavities
    used = np.zeros(m, dtype=bool)
    used[list(settings.pressurised(m))] = True
    axes = []
    for index, value in AXES:
        e = np.zeros(6 + m)
        e[index] = value
        axes.append(e)
    if used.any():
        one = np.zeros(6 + m)
        one[6 + int(np.flatnonzero(used)[0])] = 1.0
        every = np.zeros(6 + m)
        every[6:] = used
        axes += [one, every] if used.sum() > 1 else [one]
    points = []
    if settings.paths:
        h = qmc.Halton(d=6 + m, scramble=True, seed=settings.seed).random(settings.paths)
        for row in h:
            e = np.empty(6 + m)
            e[0:2] = row[0] * np.array([math.cos(2 * math.pi * row[1]), math.sin(2 * math.pi * row[1])])
            e[2] = 2.0 * row[2] - 1.0
            e[3:5] = row[3] * np.array([math.cos(2 * math.pi * row[4]), math.sin(2 * math.pi * row[4])])
            e[5] = 2.0 * row[5] - 1.0
            e[6:] = row[6:] * used
            size = np.max(np.concatenate([group_coordinates(e[:6])[[0, 2]], np.abs(e[[2, 5]]), e[6:]]))
            points.append(e / size)
    endpoints = np.array(axes + points).reshape(-1, 6 + m)
    held_out = np.zeros(len(endpoints), dtype=bool)
    held_out[len(axes):] = (np.arange(len(points)) % settings.held_out) == settings.held_out - 1
    return endpoints, held_out


# ------------------------------------------------------------------ worker side

@dataclass(frozen=True)
class PathTask:
    """Some loading paths of one segment, run in one worker (picklable)."""

    spec: Any                        # ModelSpec
    rest_translation: tuple
    rest_volumes: tuple
    stiffness: tuple                 # K (6×6) flattened: the rest tangent used by the first predictor
    mixed: tuple                     # ∂²ψ/∂s∂p at rest (6×m) flattened
    box: LoadBox
    caps: tuple                      # pose caps [lateral, axial, bending, twist]
    paths: tuple                     # ((index, endpoint tuple), ...)
    steps: int


@dataclass
class PathOutcome:
    """What a worker returns for one task: the samples and, per path, how far it got."""

    samples: Samples | None
    reached: dict = field(default_factory=dict)       # path index -> fraction of the path completed
    stopped: dict = field(default_factory=dict)       # path index -> reason
    solves: int = 0
    seconds: float = 0.0
    worker: dict = field(default_factory=dict)


def response_samples(s: np.ndarray, p: np.ndarray, responses: list, rest_translation, rest_volumes,
                     path: np.ndarray) -> Samples:
    """Convert FE responses at strains ``s`` (S, 6) and pressures ``p`` (S, m) into strain-chart samples."""
    m = p.shape[1]
    wrench = np.array([r.wrench for r in responses], dtype=float).reshape(-1, 6)
    tangent = np.array([r.tangent for r in responses], dtype=float).reshape(-1, 6, 6)
    if m:
        volumes = np.array([r.volumes for r in responses], dtype=float).reshape(-1, m)
        dv_pose = np.array([r.dvolume_dpose for r in responses], dtype=float).reshape(-1, m, 6)
        dv_p = np.array([r.dvolume_dpressure for r in responses], dtype=float).reshape(-1, m, m)
        wrench_pressure = -dv_pose.mT                                    # ∂²ψ/∂ζ∂p = −(∂V/∂ζ)ᵀ
    else:
        volumes = np.zeros((len(responses), 0))
        dv_p = np.zeros((len(responses), 0, 0))
        wrench_pressure = np.zeros((len(responses), 6, 0))
    g, H, mixed = strain_derivatives(s, rest_translation, wrench, tangent, wrench_pressure)
    return Samples(strain=s, pressure=p, gradient=g, hessian=H,
                   pressure_gradient=-(volumes - np.asarray(rest_volumes, dtype=float)),
                   mixed=mixed, pressure_hessian=-0.5 * (dv_p + dv_p.mT), path=path)


def run_paths(task: PathTask) -> PathOutcome:
    """Follow the task's loading paths (see the module docstring); one FE solve per step."""
    start = time.perf_counter()
    model = worker_model(task.spec)
    m = len(task.rest_volumes)
    K = np.array(task.stiffness).reshape(6, 6)
    mixed0 = np.array(task.mixed).reshape(6, m)
    caps = np.array(task.caps)
    rows_s, rows_p, responses, paths = [], [], [], []
    outcome = PathOutcome(samples=None)
    for index, endpoint in task.paths:
        endpoint = np.array(endpoint)
        s, p, state = np.zeros(6), np.zeros(m), None
        g, H, Hsp = np.zeros(6), K, mixed0
        reached = 0.0
        for k in range(1, task.steps + 1):
            fraction = k / task.steps
            target, target_p = task.box.loads(fraction * endpoint, m)
            try:
                step = np.linalg.solve(H, target - g - Hsp @ (target_p - p))
            except np.linalg.LinAlgError:
                outcome.stopped[index] = "singular tangent"
                break
            s_new = s + step
            if np.any(np.abs(group_coordinates(s_new)) > caps):
                # beyond the caps a softening material (St Venant-Kirchhoff) nears its instabilities:
                # samples there made its fit non-convex and 30× worse inside the caps
                outcome.stopped[index] = "pose beyond the caps"
                break
            R, t = pose_of_strain(s_new[None], task.rest_translation)
            try:
                response = model.solve(R[0], t[0], target_p if m else None, initial=state)
            except ConvergenceError as error:
                outcome.stopped[index] = f"FE did not converge ({error})"
                break
            outcome.solves += 1
            sample = response_samples(s_new[None], target_p[None], [response], task.rest_translation,
                                      task.rest_volumes, np.array([index]))
            rows_s.append(s_new)
            rows_p.append(target_p)
            responses.append(response)
            paths.append(index)
            s, p, state = s_new, target_p, response.state
            g, H, Hsp = sample.gradient[0], sample.hessian[0], sample.mixed[0]
            reached = fraction
        outcome.reached[index] = reached
    if responses:
        outcome.samples = response_samples(np.array(rows_s), np.array(rows_p).reshape(len(rows_p), m), responses,
                                           task.rest_translation, task.rest_volumes, np.array(paths))
    outcome.seconds = time.perf_counter() - start
    outcome.worker = worker_info()
    return outcome


@dataclass(frozen=True)
class PressureTask:
    """The pressure ramp that finds the inflation limit point (one worker)."""

    spec: Any
    rest_translation: tuple
    rest_volumes: tuple
    stiffness: tuple
    mixed: tuple
    cavity: int
    rest_compliance: float           # V[cavity, cavity]: the free volume compliance at rest
    largest: float                   # stop the ramp here (Pa)
    first_step: float                # Pa
    min_step: float                  # Pa: bisection resolution of the limit


@dataclass
class PressureOutcome:
    reached: float                   # largest pressure with a converged free equilibrium
    limit: float | None              # the limit point (None: none below ``largest``)
    fold: float | None               # where the fold's normal form puts the limit from the last two steps
    free_pose: list                  # group coordinates of the free pose at ``reached``
    volume_growth: list              # [(p, ΔV of the pressurised cavity)]
    solves: int
    seconds: float
    reason: str = ""


def _free_volume_compliance(H, Hsp, Hpp, cavity):
    """dΔV/dp of one cavity with the top frame free: −(Hpp − Hspᵀ H⁻¹ Hsp)."""
    eff = Hpp - Hsp.T @ np.linalg.solve(H, Hsp)
    return -eff[cavity, cavity]


#: a ramp's FE solve gives up once its load step is cut below this fraction: past the limit point
#: no equilibrium exists, and cutting down to the solver's own 1/4096 cost minutes per failure
RAMP_MIN_LOAD_STEP = 1.0 / 16.0
#: the ramp stops short of the fold's extrapolated limit point once within two ``min_step`` of it
#: and the free volume compliance has grown this much (the fold's normal form holds there)
RAMP_FOLD_COMPLIANCE = 4.0


def _fold(inverse: list) -> float | None:
    """Where the fold's normal form puts the limit point from the last two ``(p, 1/compliance)``:
    near a fold the compliance grows like 1/√(P − p), so 1/compliance² falls linearly to 0 at P."""
    if len(inverse) < 2:
        return None
    (p1, c1), (p2, c2) = inverse[-2], inverse[-1]
    return p2 + c2 ** 2 * (p2 - p1) / (c1 ** 2 - c2 ** 2) if c2 < c1 else None


def run_pressure_ramp(task: PressureTask) -> PressureOutcome:
    """Raise one cavity's pressure with the top frame free (zero load: one predictor step of
    the pose per increment) towards the inflation limit point, a continuation in few solves:
    each increment is at most ``first_step`` and at most half the way to where the fold's
    normal form (:func:`_fold`) puts the limit from the last two steps, so the ramp closes in
    on the limit geometrically instead of stepping past it (a failed FE solve beyond the limit
    costs many times a converged one; those that happen give up early,
    :data:`RAMP_MIN_LOAD_STEP`). An increment whose FE fails or whose free volume compliance
    has grown 25× over its rest value (the approach of a limit point, where it diverges) is
    halved, down to ``min_step``; the ramp also stops once the extrapolated limit is within
    two ``min_step`` (with the compliance grown :data:`RAMP_FOLD_COMPLIANCE`×). The limit is
    the last converged pressure plus that extrapolation, at most two ``min_step`` beyond it.
    The same extrapolation is reported as ``fold`` when no limit was met: where the
    ballooning heads."""
    start = time.perf_counter()
    model = worker_model(task.spec)
    m = len(task.rest_volumes)
    K = np.array(task.stiffness).reshape(6, 6)
    Hsp = np.array(task.mixed).reshape(6, m)
    s, p, state = np.zeros(6), np.zeros(m), None
    g, H = np.zeros(6), K
    step = task.first_step
    history, solves, reason = [], 0, ""
    inverse = []                                    # (p, 1/compliance) to extrapolate the limit
    compliance = task.rest_compliance
    while p[task.cavity] < task.largest and step >= task.min_step:
        fold = _fold(inverse)
        increment = step
        if fold is not None and fold > p[task.cavity]:
            if fold - p[task.cavity] <= 2 * task.min_step and compliance >= RAMP_FOLD_COMPLIANCE * task.rest_compliance:
                reason = "limit point extrapolated within two resolution steps (fold normal form)"
                break
            increment = min(step, max(0.5 * (fold - p[task.cavity]), task.min_step))
        target_p = p.copy()
        target_p[task.cavity] = min(p[task.cavity] + increment, task.largest)
        s_new = s + np.linalg.solve(H, -g - Hsp @ (target_p - p))
        R, t = pose_of_strain(s_new[None], task.rest_translation)
        try:
            response = model.solve(R[0], t[0], target_p, initial=state, min_load_step=RAMP_MIN_LOAD_STEP)
            solves += 1
        except ConvergenceError as error:
            reason = f"FE did not converge ({error})"
            step = 0.5 * increment
            continue
        sample = response_samples(s_new[None], target_p[None], [response], task.rest_translation,
                                  task.rest_volumes, np.zeros(1, dtype=int))
        g_new, H_new, Hsp_new = sample.gradient[0], sample.hessian[0], sample.mixed[0]
        try:
            trial = _free_volume_compliance(H_new, Hsp_new, sample.pressure_hessian[0], task.cavity)
        except np.linalg.LinAlgError:
            trial = np.inf
        if not (trial > 0) or trial > 25.0 * task.rest_compliance:
            reason = "free volume compliance above 25× its rest value"
            step = 0.5 * increment
            continue
        compliance = trial
        s, p, state = s_new, target_p, response.state
        g, H, Hsp = g_new, H_new, Hsp_new
        history.append((float(p[task.cavity]), float(-sample.pressure_gradient[0, task.cavity])))
        inverse.append((float(p[task.cavity]), 1.0 / compliance))
    reached = float(p[task.cavity])
    fold = _fold(inverse)
    limit = None
    if reached < task.largest:
        limit = min(max(reached, fold or reached), reached + 2 * task.min_step)
    return PressureOutcome(reached=reached, limit=limit, fold=fold, free_pose=group_coordinates(s).tolist(),
                           volume_growth=history, solves=solves, seconds=time.perf_counter() - start, reason=reason)
