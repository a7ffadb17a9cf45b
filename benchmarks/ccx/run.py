"""Run CalculiX on a deck, parse its results, cache them, and apply dead moments correctly.

Results are cached as JSON in ``benchmarks/results/ccx/<hash>.json``, keyed by a hash of the
deck text and the CalculiX version, so a re-run of the benchmark only re-solves decks that
changed.

Dead moments under NLGEOM: a moment ``M`` at vertebra ``j`` is a couple of dead forces on four
arm nodes of its rigid body (:mod:`ccx.deck`), built along the vertebra's current axes ``R`` —
unknown until solved. :func:`solve` repeats the whole analysis with ``R`` from the previous pass
until the moment the forces carry at the rotations reached matches ``M`` (``moment_residual``);
the base reactions' moment balance checks it independently.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmarks.ccx.deck import ARMS, LoadLevel, write_deck
from benchmarks.ccx.results import read_dat, step_results
from benchmarks.ccx.volume import cavity_volume
from vertebra.core.lie import so3_exp as rotation_matrix  # the vertebrae's rotation vectors → matrices

CACHE = Path(__file__).resolve().parent.parent / "results" / "ccx"


def ccx_available() -> bool:
    return shutil.which("ccx") is not None


def ccx_version() -> str:
    try:
        out = subprocess.run(["ccx", "-v"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    for line in out.splitlines():
        if "Version" in line:
            return line.strip()
    return out.strip()[:80] or "unknown"


def arm_forces(moment, rotation, arm_length: float) -> np.ndarray:
    """(4, 3) dead forces on the arm nodes ``ℓ R a_k`` (``a_k`` = +x, −x, +y, −y) carrying
    ``moment``: bending parts as forces along the vertebra's axis ``R e_z`` (like the face's
    bending stresses), torsion as tangential forces; they sum to zero."""
    R = np.asarray(rotation, float)
    ex, ey, ez = R.T
    mx, my, mz = R.T @ np.asarray(moment, float)
    b, t = 1.0 / (2.0 * arm_length), 1.0 / (4.0 * arm_length)
    return np.array([-my * b * ez + mz * t * ey, my * b * ez - mz * t * ey,
                     mx * b * ez - mz * t * ex, -mx * b * ez + mz * t * ex])


def carried_moment(forces, rotation, arm_length: float) -> np.ndarray:
    """The moment of arm forces about the frame origin with the arms turned by ``rotation``."""
    return np.cross(arm_length * ARMS @ np.asarray(rotation).T, forces).sum(axis=0)


def _environment(threads: int) -> dict:
    n = str(int(threads))
    return dict(os.environ, OMP_NUM_THREADS=n, CCX_NPROC_EQUATION_SOLVER=n, CCX_NPROC_STIFFNESS=n,
                CCX_NPROC_RESULTS=n, NUMBER_OF_PROCESSORS=n)


def _as_json(step: dict) -> dict:
    return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in step.items()}


class NotCached(RuntimeError):
    """A deck's CalculiX results are not in the cache and running CalculiX was not allowed."""


def run_deck(deck, trunk, *, threads: int = 1, cache: Path | None = CACHE, version: str | None = None,
             cached_only: bool = False) -> dict:
    """Solve ``deck`` (cached; with ``cached_only`` a deck not in the cache raises
    :class:`NotCached` instead of running CalculiX). Returns ``{"key", "wall_s", "finished", "message", "last_time",
    "steps": {k: {"translation", "rotation", "base_force", "base_rot_reaction", "volumes"}}}``
    with ``volumes`` the deformed volume of every cavity of ``trunk`` (in ``trunk.cavities``
    order) and arrays as nested lists."""
    version = version or ccx_version()
    key = hashlib.sha256((version + "\n" + deck.text).encode()).hexdigest()[:20]
    path = None if cache is None else Path(cache) / f"{key}.json"
    if path is not None and path.exists():
        return json.loads(path.read_text())
    if cached_only:
        raise NotCached(f"no cached CalculiX result {key}.json in {cache} for this deck")
    with tempfile.TemporaryDirectory(prefix="vertebra-ccx-") as tmp:
        Path(tmp, "job.inp").write_text(deck.text)
        start = time.perf_counter()
        proc = subprocess.run(["ccx", "-i", "job"], cwd=tmp, capture_output=True, text=True, env=_environment(threads))
        wall = time.perf_counter() - start
        finished = proc.returncode == 0 and "Job finished" in proc.stdout
        lines = [ln.strip() for ln in (proc.stdout + proc.stderr).splitlines() if ln.strip()]
        message = "" if finished else " | ".join([ln for ln in lines if "ERROR" in ln or "error" in ln][:3] or lines[-3:])
        dat = Path(tmp, "job.dat")
        parsed = step_results(read_dat(dat), deck) if dat.exists() else {"steps": {}, "last_time": 0.0}
    steps = {}
    for k, step in parsed["steps"].items():
        entry = {name: step[name] for name in ("translation", "rotation", "base_force", "base_rot_reaction")
                 if name in step}
        if "walls" in step:
            ids, u = step["walls"]
            x = trunk.nodes.copy()
            x[ids - 1] += u
            entry["volumes"] = np.array([cavity_volume(x, c) for c in trunk.cavities])
        steps[str(k)] = _as_json(entry)
    result = {"key": key, "ccx": version, "wall_s": wall, "finished": finished, "message": message,
              "last_time": parsed["last_time"], "n_steps": deck.n_steps, "steps": steps}
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(result))
    return result


@dataclass
class Loading:
    """Dead loads of one level (SI): forces and moments by vertebra number (at the frame
    origin, global axes), pressures by (segment, cavity), gravity (m/s²)."""

    forces: dict = field(default_factory=dict)
    moments: dict = field(default_factory=dict)
    pressures: dict = field(default_factory=dict)
    gravity: tuple = (0.0, 0.0, 0.0)


def solve(trunk, materials, loadings: list[Loading], *, nlgeom: bool = True, threads: int = 1,
          moment_tolerance: float = 1e-5, max_passes: int = 6, cache: Path | None = CACHE,
          arm_length: float | None = None, cached_only: bool = False, **deck_options) -> dict:
    """All load levels in one CalculiX run per pass; dead moments by repeated passes (module doc).

    Passes stop when, at every level reached, the moment the arm forces carry at the rotations
    reached is within ``moment_tolerance`` (relative) of the dead moment asked for (and the run
    finished, or reached no further than the pass before). Returns the last
    pass's :func:`run_deck` result plus ``passes`` (per pass: wall seconds, largest rotation
    change in rad, that moment residual) and ``moment_residual`` per step. ``cached_only``: every
    pass must be in the cache (:class:`NotCached` otherwise)."""
    version = ccx_version()
    if arm_length is None:
        arm_length = float(np.max(np.abs(trunk.nodes[:, :2])))
    has_moments = any(np.any(np.asarray(m) != 0) for L in loadings for m in L.moments.values())
    rotations = None
    passes = []
    while True:
        levels = []
        for k, L in enumerate(loadings):
            arms = {}
            # the vertebra's rotation from the previous pass at this level (or the highest level it reached)
            known = [] if rotations is None or not nlgeom else [int(i) for i in rotations if int(i) <= k + 1]
            for j, M in L.moments.items():
                R = rotation_matrix(rotations[str(max(known))][j]) if known else np.eye(3)
                arms[j] = arm_forces(M, R, arm_length)
            levels.append(LoadLevel(forces=L.forces, arm_forces=arms, pressures=L.pressures, gravity=L.gravity))
        deck = write_deck(trunk, materials, levels, nlgeom=nlgeom, arm_length=arm_length, **deck_options)
        result = run_deck(deck, trunk, threads=threads, cache=cache, version=version, cached_only=cached_only)
        new = {k: np.array(v["rotation"]) for k, v in result["steps"].items()}
        change = np.inf if rotations is None else max(
            (float(np.max(np.abs(new[k] - rotations[k]))) for k in new if k in rotations), default=np.inf)
        residual = {}
        for k, L in enumerate(loadings):
            if str(k + 1) not in new or not L.moments:
                continue
            scale = max(np.linalg.norm(M) for M in L.moments.values()) or 1.0
            R = {j: rotation_matrix(new[str(k + 1)][j]) if nlgeom else np.eye(3) for j in L.moments}
            residual[str(k + 1)] = max(float(np.linalg.norm(
                carried_moment(levels[k].arm_forces[j], R[j], arm_length) - np.asarray(M, float))) / scale
                for j, M in L.moments.items())
        passes.append({"wall_s": result["wall_s"], "key": result["key"], "finished": result["finished"],
                       "rotation_change": None if rotations is None else change,
                       "moment_residual": max(residual.values(), default=0.0)})
        # settled: the moments are right wherever the run got, and another pass would get no further
        settled = max(residual.values(), default=0.0) < moment_tolerance and (
            result["finished"] or (rotations is not None and len(new) <= len(rotations)))
        rotations = new
        if not (nlgeom and has_moments) or settled or len(passes) >= max_passes:
            break
    return dict(result, passes=passes, moment_residual=residual)
