"""Run CalculiX on a deck, parse its results, cache them, and apply dead moments correctly.

Results are cached as JSON in ``benchmarks/results/ccx/<hash>.json``, keyed by a hash of the
deck text and the CalculiX version, so a re-run of the benchmark only re-solves decks that
changed.

Dead moments under NLGEOM: the load ``q`` on a rigid body's rot node does virtual work
``q·δw`` with ``w`` the total rotation vector, while a moment ``M`` (global axes) does
``M·δθ`` with ``δθ = T(w) δw`` and ``T`` the left Jacobian of the exponential map
(``T(w) = I + (1 − cos θ)/θ² W + (θ − sin θ)/θ³ W²``). So ``q = T(w)ᵀ M`` — a function of the
unknown ``w``: :func:`solve` repeats the whole analysis with ``q`` from the previous pass until
the rotations settle, and the base reactions' moment balance verifies the carried moment.
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

from ccx.deck import LoadLevel, write_deck
from ccx.results import read_dat, step_results
from ccx.volume import cavity_volume

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


def hat(v) -> np.ndarray:
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def left_jacobian(w) -> np.ndarray:
    """T(w) with ``δθ = T(w) δw`` (spatial angular increment of ``R = exp(ŵ)``)."""
    w = np.asarray(w, float)
    t2 = float(w @ w)
    W = hat(w)
    if t2 < 1e-12:
        return np.eye(3) + 0.5 * W + W @ W / 6.0
    t = np.sqrt(t2)
    return np.eye(3) + (1 - np.cos(t)) / t2 * W + (t - np.sin(t)) / (t2 * t) * W @ W


def rotation_matrix(w) -> np.ndarray:
    w = np.asarray(w, float)
    t = np.linalg.norm(w)
    W = hat(w)
    if t < 1e-8:
        return np.eye(3) + W + 0.5 * W @ W
    return np.eye(3) + np.sin(t) / t * W + (1 - np.cos(t)) / t ** 2 * W @ W


def _environment(threads: int) -> dict:
    n = str(int(threads))
    return dict(os.environ, OMP_NUM_THREADS=n, CCX_NPROC_EQUATION_SOLVER=n, CCX_NPROC_STIFFNESS=n,
                CCX_NPROC_RESULTS=n, NUMBER_OF_PROCESSORS=n)


def _as_json(step: dict) -> dict:
    return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in step.items()}


def run_deck(deck, trunk, *, threads: int = 1, cache: Path | None = CACHE, version: str | None = None) -> dict:
    """Solve ``deck`` (cached). Returns ``{"key", "wall_s", "finished", "message", "last_time",
    "steps": {k: {"translation", "rotation", "base_force", "base_rot_reaction", "volumes"}}}``
    with ``volumes`` the deformed volume of every cavity of ``trunk`` (in ``trunk.cavities``
    order) and arrays as nested lists."""
    version = version or ccx_version()
    key = hashlib.sha256((version + "\n" + deck.text).encode()).hexdigest()[:20]
    path = None if cache is None else Path(cache) / f"{key}.json"
    if path is not None and path.exists():
        return json.loads(path.read_text())
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
          moment_tolerance: float = 1e-5, max_passes: int = 6, cache: Path | None = CACHE, **deck_options) -> dict:
    """All load levels in one CalculiX run per pass; dead moments by repeated passes (module doc).

    Returns the last pass's :func:`run_deck` result plus ``passes`` (per pass: wall seconds,
    largest rotation change in rad) and ``moment_residual`` per step — the largest difference
    between the moment the rot-node loads carry, ``T(w)⁻ᵀ q``, and the dead moment asked for,
    relative to the largest asked for."""
    version = ccx_version()
    has_moments = nlgeom and any(np.any(np.asarray(m) != 0) for L in loadings for m in L.moments.values())
    rotations = None
    passes = []
    while True:
        levels = []
        for k, L in enumerate(loadings):
            rot_loads = {}
            for j, M in L.moments.items():
                T = np.eye(3)
                if has_moments and rotations is not None and str(k + 1) in rotations:
                    T = left_jacobian(rotations[str(k + 1)][j])
                rot_loads[j] = T.T @ np.asarray(M, float)
            levels.append(LoadLevel(forces=L.forces, rot_loads=rot_loads, pressures=L.pressures, gravity=L.gravity))
        deck = write_deck(trunk, materials, levels, nlgeom=nlgeom, **deck_options)
        result = run_deck(deck, trunk, threads=threads, cache=cache, version=version)
        new = {k: np.array(v["rotation"]) for k, v in result["steps"].items()}
        change = 0.0 if rotations is None else max(
            (float(np.max(np.abs(new[k] - rotations[k]))) for k in new if k in rotations), default=np.inf)
        passes.append({"wall_s": result["wall_s"], "rotation_change": None if rotations is None else change,
                       "key": result["key"]})
        # the moments the last pass's loads carry, at the rotations it reached
        residual = {}
        for k, L in enumerate(loadings):
            if str(k + 1) not in new or not L.moments:
                continue
            scale = max(np.linalg.norm(M) for M in L.moments.values()) or 1.0
            worst = 0.0
            for j, M in L.moments.items():
                q = levels[k].rot_loads[j]
                carried = np.linalg.solve(left_jacobian(new[str(k + 1)][j]).T, q)
                worst = max(worst, float(np.linalg.norm(carried - np.asarray(M, float))) / scale)
            residual[str(k + 1)] = worst
        rotations = new
        if not has_moments or change < moment_tolerance or len(passes) >= max_passes:
            break
    result = dict(result, passes=passes, moment_residual=residual)
    return result
