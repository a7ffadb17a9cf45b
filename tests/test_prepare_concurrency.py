"""Two real ``vertebra prepare`` runs of one scene with a nonlinear (fitted) design segment, at
the same time, one of them SIGKILLed while it designs; then a third run. No conflict, the
catalogue verifies, the killed run's pool workers died with it (no orphan designs on), and
nothing is left beside the catalogue.

The segment is the coarse neo-Hookean rod of ``fitted_energies`` (P2, h 8 mm, 8 paths × 4
steps: ~6 s to design alone on a quiet machine); two runs on two cores with their workers'
imports take ~30 s, hence ``slow``.
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from vertebra.solver.scene import scene_toml
from vertebra.store import catalogue, shards

from fitted_energies import ROD, ROD_MESH, ROD_SAMPLING

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads process trees from /proc")]

def _scene(directory: Path) -> Path:
    segment = {"type": "design", "family": "rod", "parameters": dict(ROD), "mesh_size": ROD_MESH,
               "material": "neo_hookean", "count": 1,
               "sampling": {"paths": ROD_SAMPLING["paths"], "steps": ROD_SAMPLING["steps"]}}
    data = {"name": "concurrent prepare", "catalogue": {"path": "cat.h5"}, "segment": [segment],
            "cable": [{"name": "pull", "radius": 0.004, "to": 1, "tension": 0.5, "max_tension": 2.0}],
            "effector": [{"name": "tip", "target": [0.004, 0.0, 0.039]}]}
    path = directory / "scene.toml"
    path.write_text(scene_toml(data))
    return path


def _prepare(scene: Path, *extra: str) -> subprocess.Popen:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    return subprocess.Popen([sys.executable, "-m", "vertebra.cli.main", "prepare", str(scene), "--workers", "1",
                             "--no-accuracy", "--no-progress", "--json", *extra],
                            cwd=scene.parent, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _children() -> dict[int, list[int]]:
    tree: dict[int, list[int]] = {}
    for name in os.listdir("/proc"):
        if name.isdigit():
            try:
                with open(f"/proc/{name}/stat") as fh:
                    ppid = int(fh.read().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            tree.setdefault(ppid, []).append(int(name))
    return tree


def _descendants(pid: int) -> set[int]:
    tree, out, todo = _children(), set(), [pid]
    while todo:
        for child in tree.get(todo.pop(), []):
            out.add(child)
            todo.append(child)
    return out


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except (FileNotFoundError, IndexError):
        return False


def _cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            return fh.read().replace(b"\0", b" ").decode(errors="replace")[:200]
    except OSError:
        return "?"


def _is_worker(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            cmdline = fh.read()
    except OSError:
        return False
    return b"resource_tracker" not in cmdline


def test_two_prepares_one_killed_then_a_rerun(tmp_path):
    rng = random.Random(21)
    scene = _scene(tmp_path)
    path = tmp_path / "cat.h5"
    survivor, victim = _prepare(scene), _prepare(scene)
    seen: set[int] = set()
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not any(_is_worker(p) for p in seen):
            seen |= _descendants(victim.pid)          # its pool workers: spawned once it designs
            assert victim.poll() is None, f"the run to kill ended first: {victim.communicate()}"
            time.sleep(0.05)
        assert any(_is_worker(p) for p in seen), "the run to kill never started a pool worker"
        stop = time.monotonic() + rng.uniform(1.0, 3.0)   # mid-design: the worker is sampling paths
        while time.monotonic() < stop:
            seen |= _descendants(victim.pid)
            time.sleep(0.05)
        assert victim.poll() is None, "the run to kill finished before it was killed: test too weak"
        victim.send_signal(signal.SIGKILL)
        victim.wait(30)
        deadline = time.monotonic() + 5              # the kernel's PDEATHSIG, else the watchdog (0.5 s)
        while time.monotonic() < deadline and any(_alive(p) for p in seen):
            time.sleep(0.1)
        orphans = {p: _cmdline(p) for p in seen if _alive(p)}
        assert orphans == {}, f"processes of the killed run still running: {orphans}"

        out, err = survivor.communicate(timeout=600)
        assert survivor.returncode == 0, err
        first = json.loads(out)
        assert first["failed"] == [] and first["failures"] == []
        [key] = [s["key"] for s in first["segments"]]
        assert key in first["designed"] + first["reused"]
    finally:
        for p in (survivor, victim):
            if p.poll() is None:
                p.kill()
                p.wait()
        for p in seen:
            if _alive(p):
                os.kill(p, signal.SIGKILL)

    rerun = _prepare(scene)
    out, err = rerun.communicate(timeout=600)
    assert rerun.returncode == 0, err
    again = json.loads(out)
    assert again["designed"] == [] and key in again["reused"]         # nothing to design any more
    assert catalogue.verify(path) == [] and shards.problem_files(path) == []
    check = subprocess.run([sys.executable, "-m", "vertebra.cli.main", "catalogue", "verify", str(path)],
                           capture_output=True, text=True)
    assert check.returncode == 0, check.stdout + check.stderr
    with catalogue.open_catalogue(path) as cat:
        assert key in cat.keys() and cat.pending == []
    beside = sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("cat.h5"))
    assert beside == ["cat.h5"], beside                  # no lock file, no shards directory, no conflict
