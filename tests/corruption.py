"""Seeded corruption fuzz of a catalogue, shared by tests/test_catalogue_hostile.py (a small run)
and benchmarks/bench_catalogue_fuzz.py (a large one).

A valid catalogue of real designed entries (coarse meshes: every family the store has bounds
for, cavities included) is corrupted — bit flips, zeroed blocks, truncation, random bytes —
and every command a user would run on it goes through ``vertebra.cli.main`` in a forked child
with a deadline: ``catalogue verify``, ``catalogue ls``, ``catalogue show`` and ``simulate``
of a scene built on the catalogue. Outcomes per command:

* ``ok`` (exit 0) or ``refused`` (exit 2 with a one-line message) or ``exit-1`` (simulate only:
  not converged), which are fine;
* ``traceback`` (an exception escaped the CLI) and ``hang`` (the deadline passed), which are not;
* ``unsound``: a command succeeded on data that differ from the original — verify said OK but
  an entry differs, show printed a different entry, simulate gave a different shape.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import select
import signal
import time
import traceback
import warnings
from pathlib import Path

import numpy as np

SPECS = [
    ("rod", dict(radius=0.01, length=0.04, youngs_modulus=1e6, poisson_ratio=0.3, density=1000.0), 0.01),
    ("tube", dict(outer_radius=0.01, inner_radius=0.006, length=0.03, youngs_modulus=2e6, poisson_ratio=0.4,
                  density=1100.0), 0.006),
    ("bellows", dict(inner_radius=0.008, outer_radius=0.014, wall_thickness=0.0015, length=0.04,
                     youngs_modulus=1e6, poisson_ratio=0.45), 0.004),
    ("pneumatic", dict(outer_radius=0.02, chamber_radius=0.005, chamber_offset=0.011, length=0.02,
                       youngs_modulus=1e6, poisson_ratio=0.45, density=1100.0), 0.008),
]

SCENE = """
[catalogue]
path = "{catalogue}"

[[segment]]
type = "entry"
entry = "fuzz-pneumatic"
count = 3

[[segment]]
type = "entry"
entry = "fuzz-rod"
count = 2

[[chamber]]
name = "c0"
cavity = 0
from = 1
to = 3
pressure = 2000.0

[[load]]
vertebra = -1
force = [0.002, 0.0, 0.0]
"""

KINDS = ("bit flips", "zeroed block", "truncation", "random bytes")


def build_catalogue(directory: Path) -> Path:
    """The valid catalogue the fuzz corrupts (P1, coarse: ~0.5 s)."""
    from vertebra.designer.segment import design_segment
    from vertebra.store import catalogue

    path = Path(directory) / "valid.h5"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")            # order-1 locking warnings: not the point here
        entries = [design_segment(family, p, mesh_size=h, order=1, name=f"fuzz-{family}", estimate_accuracy=False)
                   for family, p, h in SPECS]
    catalogue.add_entries(path, entries)
    return path


def corrupt(data: bytes, seed: int) -> tuple[str, bytes]:
    """One seeded corruption of ``data``: (kind, corrupted bytes)."""
    rng = np.random.default_rng(seed)
    kind = KINDS[seed % len(KINDS)]
    buf = bytearray(data)
    n = len(buf)
    if kind == "bit flips":
        for _ in range(int(rng.integers(1, 9))):
            i = int(rng.integers(0, n))
            buf[i] ^= 1 << int(rng.integers(0, 8))
    elif kind == "zeroed block":
        start, length = int(rng.integers(0, n)), int(rng.integers(1, 4097))
        buf[start:start + length] = bytes(len(buf[start:start + length]))
    elif kind == "truncation":
        del buf[int(rng.integers(0, n)):]
    else:
        start, length = int(rng.integers(0, n)), int(rng.integers(1, 257))
        buf[start:start + length] = rng.integers(0, 256, size=len(buf[start:start + length]), dtype=np.uint8).tobytes()
    return kind, bytes(buf)


def _cli(argv) -> tuple[str, int, str, str]:
    """Run ``vertebra ARGV``: (outcome, exit code, stdout, stderr)."""
    from vertebra.cli.main import main

    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main(list(argv))
    except SystemExit as exc:                    # argparse
        code = exc.code if isinstance(exc.code, int) else 2
    except BaseException:                        # noqa: BLE001 — exactly what the fuzz looks for
        return "traceback", -1, out.getvalue(), traceback.format_exc(limit=-3)
    outcome = {0: "ok", 2: "refused", 1: "exit-1"}.get(code, f"exit-{code}")
    return outcome, code, out.getvalue(), err.getvalue()


def _digests(path) -> dict | None:
    """content digest per key of every entry (None if the catalogue does not open)."""
    from vertebra.store import catalogue
    from vertebra.core.errors import CatalogueError
    from vertebra.store.schema import EncodedEntry

    try:
        with catalogue.open_catalogue(path) as cat:
            return {k: EncodedEntry(cat.load(k)).checksum for k in cat.keys()}
    except CatalogueError:
        return None


def reference(valid: Path, directory: Path) -> dict:
    """What the commands print for the valid catalogue (the fuzz compares with it)."""
    scene = Path(directory) / "scene.toml"
    scene.write_text(SCENE.format(catalogue=valid.name))
    outcome, _, out, err = _cli(["simulate", str(scene), "--json"])
    assert outcome == "ok", err
    show = {}
    for family, *_ in SPECS:
        _, _, text, _ = _cli(["catalogue", "show", str(valid), f"fuzz-{family}", "--json"])
        show[f"fuzz-{family}"] = json.loads(text)["checksum"]
    return {"digests": _digests(valid), "vertebrae": json.loads(out)["vertebrae"], "show": show}


def run_case(data: bytes, seed: int, directory: Path, ref: dict) -> dict:
    """Corrupt, write ``case.h5`` + scene, run the four commands; outcomes per command."""
    kind, bad = corrupt(data, seed)
    directory = Path(directory)
    path = directory / "case.h5"
    path.write_bytes(bad)
    scene = directory / "case.toml"
    scene.write_text(SCENE.format(catalogue=path.name))
    name = f"fuzz-{SPECS[seed % len(SPECS)][0]}"
    result = {"seed": seed, "kind": kind, "changed": bad != data}
    outcome, _, out, err = _cli(["catalogue", "verify", str(path)])
    result["verify"] = outcome
    if outcome == "ok" and _digests(path) != ref["digests"]:
        result["verify"] = "unsound"
    result["ls"] = _cli(["catalogue", "ls", str(path), "--json"])[0]
    outcome, _, out, err = _cli(["catalogue", "show", str(path), name, "--json"])
    if outcome == "ok" and json.loads(out).get("checksum") != ref["show"][name]:
        outcome = "unsound"
    result["show"] = outcome
    outcome, _, out, err = _cli(["simulate", str(scene), "--json"])
    if outcome == "ok" and json.loads(out)["vertebrae"] != ref["vertebrae"]:
        outcome = "unsound"
    result["simulate"] = outcome
    result["detail"] = {c: result[c] for c in ("verify", "ls", "show", "simulate")
                        if result[c] in ("traceback", "unsound")}
    if result["detail"]:
        result["message"] = err[-2000:]
    return result


def run_forked(data: bytes, seed: int, directory: Path, ref: dict, deadline_s: float) -> dict:
    """``run_case`` in a forked child; a child that passes ``deadline_s`` is killed: "hang"."""
    read_fd, write_fd = os.pipe()
    start = time.perf_counter()
    pid = os.fork()
    if pid == 0:                                   # child
        os.close(read_fd)
        code = 0
        try:
            payload = json.dumps(run_case(data, seed, directory, ref)).encode()
        except BaseException:                      # noqa: BLE001
            payload = json.dumps({"seed": seed, "harness_error": traceback.format_exc()}).encode()
            code = 1
        with os.fdopen(write_fd, "wb") as fh:
            fh.write(payload)
        os._exit(code)
    os.close(write_fd)
    chunks = []
    with os.fdopen(read_fd, "rb") as fh:
        while True:
            remaining = deadline_s - (time.perf_counter() - start)
            ready, _, _ = select.select([fh], [], [], max(0.0, remaining))
            if not ready:
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
                return {"seed": seed, "kind": KINDS[seed % len(KINDS)], "hang": True,
                        **{c: "hang" for c in ("verify", "ls", "show", "simulate")}}
            chunk = os.read(fh.fileno(), 1 << 16)
            if not chunk:
                break
            chunks.append(chunk)
    os.waitpid(pid, 0)
    result = json.loads(b"".join(chunks) or b"{}")
    result["seconds"] = time.perf_counter() - start
    return result


def fuzz(directory: Path, seeds, deadline_s: float = 30.0) -> tuple[list[dict], dict]:
    """Run the seeded cases; returns (results, outcome counts per command)."""
    directory = Path(directory)
    valid = build_catalogue(directory)
    ref = reference(valid, directory)
    data = valid.read_bytes()
    results = [run_forked(data, seed, directory, ref, deadline_s) for seed in seeds]
    counts: dict = {}
    for r in results:
        for command in ("verify", "ls", "show", "simulate"):
            outcome = r.get(command, "harness error")
            counts.setdefault(command, {}).setdefault(outcome, 0)
            counts[command][outcome] += 1
    return results, counts
