"""QA: a seeded fuzzer over the command line — its flags, the scenes, trajectories and sweep specs
it reads (mutated tables, corrupted bytes, hostile paths) — run in one subprocess capped at
2 GiB of address space, each case under a 20 s alarm on its CPU time (and a 60 s one on the
wall clock, for a case that waits instead of computing).

Every case must end with exit code 0, 1 or 2, no traceback, and when it is refused (2) the
refusal is one line on stderr (``vertebra COMMAND: error: …``; argparse's usage lines and
one-line warnings aside). A case that runs out of its time is a hang; one that exhausts the
2 GiB is a MemoryError — both fail the test. The flags come from the parser itself (a new
option is fuzzed without editing this file), their values from pools of the values users get
wrong: negative, zero, huge, NaN, infinite, non-numbers, empty, ``/dev/zero``, directories,
missing files, names with NUL bytes. Options that would reach the network (``--scheduler``),
start a dask cluster, run the demo, or design nonlinear entries (minutes) are left out; a
design is capped at 3,000 elements so that a valid one stays fast.

Run as a script it is the worker: ``python test_qa_cli_fuzz.py SEED SECONDS DIR`` prints one
JSON line per case.
"""

from __future__ import annotations

import copy
import json
import os
import random
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
GALLERY = ROOT / "solver" / "gallery"
SWEEPS = ROOT / "examples" / "sweeps"
CASE_SECONDS = 20            # a case that computes longer (CPU time: the machine's load aside) is a hang
WALL_SECONDS = 60            # ... or that takes longer on the wall clock (waiting on a lock or a file)
BUDGET_SECONDS = 18          # the worker starts no new case after this (the test stays under 30 s)
MEMORY = 2 << 30             # bytes of address space for the worker

# never fuzzed: the network (a scheduler address), a dask cluster, the end-to-end demo
EXCLUDED_OPTIONS = {"--scheduler"}
EXCLUDED_COMMANDS = {"demo"}
NUMBERS = ["-1", "0", "1", "2", "3", "8", "16", "100000000", "1e8", "9223372036854775808", "-9223372036854775809",
           "nan", "inf", "-inf", "1e-300", "1e300", "0.5", "x", "", " ", "1,5", "0x10"]
WORDS = ["", "x", "linear", "svk", "penalty", "least", "tick", "converged", "sobol", "serial", "local", "qp",
         "gauss_seidel", "é", "-", "--json"]


# ---------------------------------------------------------------------------- inputs
def _mutate(rnd: random.Random, data):
    """One to three random edits of a parsed TOML document (a value replaced, a field dropped
    or added, a number scaled)."""
    values = ["x", "", True, [], [1.0, 2.0, 3.0], {}, {"a": 1}, 0, -1, 7, 10**9, 0.0, -0.5, float("inf"),
              float("nan"), 1e-300, 1e300, 2**63 - 1, "é\u0000", [[[[[]]]]]]
    for _ in range(rnd.randint(1, 3)):
        paths = list(_paths(data))
        if not paths:
            return data
        path = rnd.choice(paths)
        parent = data
        for key in path[:-1]:
            parent = parent[key]
        key, op = path[-1], rnd.random()
        if op < 0.5:
            parent[key] = copy.deepcopy(rnd.choice(values))
        elif op < 0.65:
            del parent[key]
        elif op < 0.8 and isinstance(parent, dict):
            parent[f"extra_{rnd.randint(0, 9)}"] = 1
        elif isinstance(parent[key], (int, float)) and not isinstance(parent[key], bool):
            parent[key] = parent[key] * rnd.choice([-1, 0, 1e3, 1e-3, 1e12])
    return data


def _paths(d, prefix=()):
    items = d.items() if isinstance(d, dict) else enumerate(d) if isinstance(d, list) else ()
    for k, v in items:
        yield prefix + (k,)
        yield from _paths(v, prefix + (k,))


def _toml(data) -> str:
    from vertebra.solver.scene import scene_toml

    return scene_toml(data)


def _corrupt(rnd: random.Random, text: str) -> bytes:
    """Byte-level damage: truncation, a Latin-1 byte, a NUL, a random byte run, deep nesting."""
    raw = text.encode()
    op = rnd.randrange(5)
    at = rnd.randrange(len(raw) + 1)
    if op == 0:
        return raw[:at]
    if op == 1:
        return raw[:at] + b"\xe9" + raw[at:]
    if op == 2:
        return raw[:at] + b"\x00" + raw[at:]
    if op == 3:
        return raw[:at] + bytes(rnd.randrange(256) for _ in range(16)) + raw[at:]
    depth = rnd.choice([40, 400, 4000])
    return raw + b"\nnested = " + b"[" * depth + b"]" * depth + b"\n"


class Inputs:
    """The files the cases read, written once into ``directory``."""

    def __init__(self, rnd: random.Random, directory: Path):
        self.rnd, self.dir = rnd, directory
        self.scenes = [p for p in sorted(GALLERY.glob("*.toml"))]
        self.runtime = [p for p in self.scenes if "design" not in p.stem and p.stem != "paper_5v_16t"]
        self.specs = sorted(SWEEPS.glob("*.toml"))
        (directory / "adir").mkdir()
        (directory / "trajectory.csv").write_text("t,tip.x,tip.y,tip.z\n0,0.001,0.0,0.089\n1,0.002,0.0,0.089\n")
        (directory / "mm.csv").write_text("tip.x,tip.y,tip.z\n2,1,89\n")
        (directory / "binary.bin").write_bytes(bytes(range(256)))
        self.count = 0

    def _write(self, name: str, content) -> str:
        self.count += 1
        path = self.dir / f"{self.count}_{name}"
        path.write_bytes(content if isinstance(content, bytes) else content.encode())
        return str(path)

    def scene(self, runtime: bool = True) -> str:
        rnd = self.rnd
        source = rnd.choice(self.runtime if runtime else self.scenes)
        op = rnd.random()
        if op < 0.3:
            return str(source)
        if op < 0.75:
            data = _mutate(rnd, tomllib.loads(source.read_text()))
            try:
                return self._write("scene.toml", _toml(data))
            except (TypeError, ValueError):
                return str(source)
        if op < 0.9:
            return self._write("scene.toml", _corrupt(rnd, source.read_text()))
        return rnd.choice(self.hostile())

    def spec(self) -> str:
        rnd = self.rnd
        source = rnd.choice(self.specs)
        op = rnd.random()
        if op < 0.2:
            return str(source)
        if op < 0.75:
            data = _mutate(rnd, tomllib.loads(source.read_text()))
            try:
                return self._write("spec.toml", _toml(data))
            except (TypeError, ValueError):
                return str(source)
        if op < 0.9:
            return self._write("spec.toml", _corrupt(rnd, source.read_text()))
        return rnd.choice(self.hostile())

    def trajectory(self) -> str:
        rnd = self.rnd
        op = rnd.random()
        if op < 0.3:
            return str(self.dir / rnd.choice(["trajectory.csv", "mm.csv"]))
        if op < 0.7:
            text = (self.dir / "trajectory.csv").read_text()
            return self._write("trajectory.csv", _corrupt(rnd, text))
        return rnd.choice(self.hostile())

    def hostile(self) -> list[str]:
        return ["/dev/zero", "/dev/null", str(self.dir / "adir"), str(self.dir / "missing.toml"),
                str(self.dir / "binary.bin"), "a\x00b.toml", "", "gallery:nothing"]

    def output(self, suffix: str) -> str:
        rnd = self.rnd
        choice = rnd.random()
        if choice < 0.5:
            return str(self.dir / f"out{self.count}{suffix}")
        return rnd.choice([str(self.dir / "adir"), str(self.dir / "out.txt"), str(self.dir / "no" / f"x{suffix}"),
                           "/dev/zero", "/dev/null", "", "o\x00ut" + suffix])


# ---------------------------------------------------------------------------- argv
def _commands():
    from vertebra.cli.main import build_parser

    parser = build_parser()
    [sub] = [a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction"]
    return {name: p for name, p in sub.choices.items() if name not in EXCLUDED_COMMANDS}


def _value(rnd: random.Random, action, inputs: Inputs, command: str):
    option = action.option_strings[0] if action.option_strings else action.dest
    if action.choices is not None and not isinstance(action.choices, dict):
        pool = [str(c) for c in action.choices]
        return rnd.choice(pool) if rnd.random() < 0.8 else rnd.choice(WORDS)
    if option == "--trajectory":
        return inputs.trajectory()
    if option in ("--plot",):
        return inputs.output(".png")
    if option in ("--vtk",):
        return inputs.output(rnd.choice([".vtp", ".pvd"]))
    if option in ("--frames", "--points"):
        return inputs.output(rnd.choice([".csv", ".npz"]))
    if option in ("--catalogue", "--export-mesh", "--out"):
        return inputs.output(rnd.choice([".h5", ".msh", ".vtu"]))
    if option == "--where":
        return rnd.choice(["radius>0.01", "radius=", "x>>1", "name='a'", "radius=" + "[" * 50 + "]" * 50, ""])
    if option in ("--set", "--sampling"):
        name = rnd.choice(["radius", "length", "youngs_modulus", "poisson_ratio", "outer_radius", "paths", "x", ""])
        return f"{name}={rnd.choice(NUMBERS)}"
    if action.type in (int, float):
        return rnd.choice(NUMBERS)
    return rnd.choice(WORDS + NUMBERS)


def _argv(rnd: random.Random, commands: dict, inputs: Inputs) -> list[str]:
    command = rnd.choice(sorted(commands))
    parser = commands[command]
    if command == "catalogue":
        [sub] = [a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction"]
        action = rnd.choice(sorted(sub.choices))
        return ["catalogue", action, *_options(rnd, sub.choices[action], inputs, "catalogue")]
    return [command, *_options(rnd, parser, inputs, command)]


def _options(rnd, parser, inputs, command) -> list[str]:
    argv = []
    for action in parser._actions:
        if action.dest == "help" or set(action.option_strings) & EXCLUDED_OPTIONS:
            continue
        if not action.option_strings:            # a positional
            if action.dest == "scene":
                argv.append(inputs.scene(runtime=command != "prepare"))
            elif action.dest == "spec":
                argv.append(inputs.spec())
            elif action.dest == "family":
                argv.append(rnd.choice(["rod", "tube", "bellows", "pneumatic", "tapered_pneumatic", "vertebra", "x"]))
            elif action.dest == "directory":
                argv.append(str(inputs.dir / f"examples{inputs.count}"))
            elif action.nargs in ("+", "*"):
                argv += [inputs.output(".h5") for _ in range(rnd.randint(0, 2))]
            else:
                argv.append(rnd.choice([inputs.output(".h5"), "x", str(inputs.dir / "missing.h5")]))
            continue
        if rnd.random() < 0.6:
            continue
        if action.nargs == 0:
            argv.append(action.option_strings[0])
        else:
            argv += [action.option_strings[0], _value(rnd, action, inputs, command)]
    if command in ("sweep", "prepare"):
        argv.append("--dry-run")                  # planning only: designing is the designer's tests' job
    if command in ("sweep", "prepare", "simulate", "invert", "workspace"):
        argv += ["--executor", "serial"]          # no pool of processes, no dask cluster
    if command == "design":
        argv += ["--max-elements", "3000", "--no-accuracy", "--material", "linear"]
    if command == "workspace" and "--samples" not in argv:
        argv += ["--samples", "8"]
    return argv


# ---------------------------------------------------------------------------- the worker
class Hang(BaseException):
    """Raised by the alarms in a case that computes longer than CASE_SECONDS (its process's CPU
    time, so that a loaded machine does not turn a slow case into a hang) or waits longer than
    WALL_SECONDS."""


def _run_case(argv: list[str]) -> dict:
    import contextlib
    import io
    import signal
    import traceback
    import warnings

    from vertebra.cli.main import main

    def alarm(signum, frame):
        raise Hang()

    out, err = io.StringIO(), io.StringIO()
    signal.signal(signal.SIGALRM, alarm)
    signal.signal(signal.SIGPROF, alarm)
    signal.setitimer(signal.ITIMER_PROF, CASE_SECONDS)
    signal.alarm(WALL_SECONDS)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings():
            try:
                code = main(argv)
            except SystemExit as done:            # argparse: usage and one error line, exit 2
                code = done.code if isinstance(done.code, int) else 2
    except Hang:
        code, err = "hang", io.StringIO("hang")
    except BaseException:                        # noqa: BLE001 — what the executable would print as a traceback
        code = "traceback"
        err.write(traceback.format_exc())
    finally:
        signal.alarm(0)
        signal.setitimer(signal.ITIMER_PROF, 0)
    return {"argv": argv, "code": code, "stderr": err.getvalue()[-3000:]}


def worker(seed: int, seconds: float, directory: Path) -> None:
    import resource
    import time

    resource.setrlimit(resource.RLIMIT_AS, (MEMORY, MEMORY))
    os.chdir(directory)                           # relative names ("x") land in the test's directory
    rnd = random.Random(seed)
    inputs = Inputs(rnd, directory)
    commands = _commands()
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        argv = _argv(rnd, commands, inputs)
        result = _run_case(argv)
        print(json.dumps(result), flush=True)
        if result["code"] == "hang":
            break


# ---------------------------------------------------------------------------- the test
def _problems(result: dict) -> str | None:
    code, lines = result["code"], result["stderr"].splitlines()
    if code not in (0, 1, 2):
        return f"exit {code}"
    if "Traceback" in result["stderr"]:
        return "a traceback on stderr"
    if "out of memory" in result["stderr"]:
        return "memory exhausted (an input limit is missing)"
    if code == 2:
        said = [line for line in lines if ": error: " in line or line.startswith("error:")]
        if len(said) != 1:
            return f"refused without one error line: {lines[-4:]}"
    return None


@pytest.mark.parametrize("seed", [1, 2])
def test_cli_fuzz_no_traceback_no_hang_bounded_memory(seed, tmp_path):
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MPLBACKEND="Agg")
    done = subprocess.run([sys.executable, __file__, str(seed), str(BUDGET_SECONDS / 2), str(tmp_path)],
                          capture_output=True, text=True, timeout=WALL_SECONDS + BUDGET_SECONDS + 30, env=env,
                          cwd=tmp_path)
    results = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]
    assert done.returncode == 0, done.stderr[-3000:]
    bad = [(r["argv"], problem, r["stderr"][-800:]) for r in results if (problem := _problems(r))]
    assert bad == [], json.dumps(bad[:3], indent=1)
    codes = {r["code"] for r in results}
    assert len(results) >= 10 and 2 in codes, (len(results), codes)     # it ran, and refused some inputs


if __name__ == "__main__":
    worker(int(sys.argv[1]), float(sys.argv[2]), Path(sys.argv[3]))
