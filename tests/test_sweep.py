"""Sweep machinery with a cheap fake job: spec parsing, expansion, resume, failure isolation.

The real designer/catalogue end-to-end sweeps are in tests/test_sweep_real.py.
The fake designer and store below are module-level so spawned worker processes can import it.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np
import pytest

from vertebra.designer.executors import EXECUTORS, Crash, make_executor
from vertebra.designer.sweep import (CatalogueStore, expand, failure_log_path, latin_hypercube_unit, load_spec,
                                     parse_spec, plan_sweep, run_sweep)
from vertebra.store import catalogue
from vertebra.store.entry import SegmentEntry, content_key
from vertebra.core.errors import CatalogueError, GeometryError, OptionError, SpecError

# --------------------------------------------------------------------------- fake designer and store

CALLS = []          # tasks the fake job saw (serial executor only: same process)


def fake_canonical(family, parameters):
    out = {"youngs_modulus": 1.0e6, "poisson_ratio": 0.3, **parameters}
    for name in ("radius", "length"):
        if name not in out:
            raise GeometryError(f"parameter {name!r} is required")
        if not out[name] > 0:
            raise GeometryError(f"parameter {name!r} must be > 0, got {out[name]}")
    return out


def fake_key(task):
    return content_key({"family": task.family, "parameters": task.parameters, **task.key_options})


def fake_job(task):
    CALLS.append(task.index)
    p = task.parameters
    if p.get("explode"):
        raise RuntimeError(f"boom in task {task.index}")
    if p.get("crash"):
        os._exit(3)                                      # a worker dying hard (segfault-like)
    # beam compliances of the rod: fake, but physical (the store checks entries against their family)
    L, E, area = p["length"], p["youngs_modulus"], np.pi * p["radius"] ** 2
    inertia, shear = area * p["radius"] ** 2 / 4, E / (2 * (1 + p.get("poisson_ratio", 0.3)))
    compliance = np.diag([L ** 3 / (3 * E * inertia)] * 2 + [L / (E * area)] + [L / (E * inertia)] * 2
                         + [L / (shear * 2 * inertia)])
    return SegmentEntry(key=fake_key(task), name=task.name or f"fake-{task.index}", family=task.family,
                        parameters=p, compliance=compliance, cavity_volumes=[], mass=0.0,
                        center_of_mass=[0, 0, p["length"] / 2], rest_translation=[0, 0, p["length"]],
                        provenance={"omp": os.environ.get("OMP_NUM_THREADS")})


def fake_store(path, entry):
    """A stand-in catalogue: one JSON line per entry (appends are atomic enough for a test)."""
    with open(path, "a") as handle:
        handle.write(json.dumps({"key": entry.key, "name": entry.name}) + "\n")
    return entry.key


def stored_keys(path):
    if not os.path.exists(path):
        return []
    return [json.loads(line)["key"] for line in Path(path).read_text().splitlines()]


@dataclass(frozen=True)
class JsonLinesStore:
    """The sweep's store Protocol over the stand-in catalogue; asked per key, nothing to merge."""

    path: str

    def keys(self):
        return None

    def has(self, key):
        return key in stored_keys(self.path)

    def add(self, entry):
        return fake_store(self.path, entry)

    def consolidate(self):
        pass


@dataclass(frozen=True)
class FakeDesigner:
    """The sweep's designer Protocol with the cheap fake job (module level: spawned workers import it)."""

    job: Callable = fake_job
    known: tuple | None = ("rod", "tube")

    def families(self):
        return self.known

    def canonical(self, family, parameters):
        return fake_canonical(family, parameters)

    def key(self, task):
        return fake_key(task)

    def design(self, task):
        return self.job(task)


FAKE = FakeDesigner()


def spec_dict(**sampler):
    return {"family": "rod", "parameters": {"youngs_modulus": 2.0e6}, "mesh_size": 0.004, "order": 1,
            **sampler}


def run_fake(spec, catalogue, **kwargs):
    kwargs.setdefault("executor", "serial")
    return run_sweep(spec, catalogue, store=JsonLinesStore, designer=FAKE, progress=False, **kwargs)


# --------------------------------------------------------------------------- expansion

def test_grid_is_the_cartesian_product_in_spec_order():
    spec = parse_spec(spec_dict(grid={"radius": [0.01, 0.02, 0.03], "length": [0.04, 0.05]}))
    tasks = expand(spec)
    assert [(t.parameters["radius"], t.parameters["length"]) for t in tasks] == [
        (0.01, 0.04), (0.01, 0.05), (0.02, 0.04), (0.02, 0.05), (0.03, 0.04), (0.03, 0.05)]
    assert all(t.parameters["youngs_modulus"] == 2.0e6 and t.options["mesh_size"] == 0.004 and t.options["order"] == 1
               for t in tasks)
    assert [t.index for t in tasks] == list(range(6))


def test_list_accepts_array_of_tables_and_sets():
    sets = [{"radius": 0.01, "length": 0.04}, {"radius": 0.02, "length": 0.03, "poisson_ratio": 0.45}]
    for form in (sets, {"sets": sets}):
        tasks = expand(parse_spec(spec_dict(list=form)))
        assert [t.parameters for t in tasks] == [{"youngs_modulus": 2.0e6, **s} for s in sets]


@pytest.mark.parametrize("samples, seed", [(7, 0), (20, 3)])
def test_lhs_puts_one_sample_in_every_stratum(samples, seed):
    # Latin hypercube property, checked in the sampled (linear or log) coordinate:
    # for every parameter, floor(n * fraction) over the n samples is a permutation
    # of 0..n-1. Values are rounded to 6 significant digits, which moves a fraction
    # by < 1e-5; the 1e-5 margin only guards the range ends, strata are 1/n >= 0.05
    # wide (a sample that close to an inner stratum edge would fail this test).
    lhs = {"ranges": {"radius": [0.004, 0.012], "youngs_modulus": [1e5, 1e8]}, "samples": samples,
           "seed": seed, "log": ["youngs_modulus"]}
    tasks = expand(parse_spec({"family": "rod", "parameters": {"length": 0.04}, "lhs": lhs}))
    assert len(tasks) == samples
    r = np.array([t.parameters["radius"] for t in tasks])
    e = np.array([t.parameters["youngs_modulus"] for t in tasks])
    fractions = {"radius": (r - 0.004) / 0.008, "youngs_modulus": (np.log10(e) - 5.0) / 3.0}
    for name, u in fractions.items():
        assert np.all((u > -1e-5) & (u < 1 + 1e-5)), name
        strata = np.floor(np.clip(u, 0, 1 - 1e-12) * samples).astype(int)
        assert all(float(f"{v:.6g}") == v for v in (r if name == "radius" else e)), name   # 6 digits kept
        assert sorted(strata) == list(range(samples)), name
    # seeded: the same seed gives the same tasks (resume relies on it), another seed does not
    again = expand(parse_spec({"family": "rod", "parameters": {"length": 0.04}, "lhs": lhs}))
    assert [t.parameters for t in again] == [t.parameters for t in tasks]
    other = expand(parse_spec({"family": "rod", "parameters": {"length": 0.04}, "lhs": {**lhs, "seed": seed + 1}}))
    assert [t.parameters for t in other] != [t.parameters for t in tasks]


def test_lhs_unit_sampler_stratifies_in_every_dimension():
    u = latin_hypercube_unit(4, 50, seed=11)
    for column in u.T:
        assert sorted(np.floor(column * 50).astype(int)) == list(range(50))


def test_lhs_integer_parameters_are_rounded():
    lhs = {"ranges": {"convolutions": [2, 6], "radius": [0.01, 0.02]}, "samples": 5, "seed": 1,
           "integer": ["convolutions"]}
    tasks = expand(parse_spec({"family": "bellows", "lhs": lhs}))
    values = [t.parameters["convolutions"] for t in tasks]
    assert all(isinstance(v, int) and 2 <= v <= 6 for v in values)


# --------------------------------------------------------------------------- bad specs

@pytest.mark.parametrize("data, field", [
    ({"family": "rod", "grid": {"radius": [0.01]}, "mesh_sise": 0.004}, "mesh_sise"),
    ({"family": "rod", "grid": {"radius": 0.01}}, "grid.radius"),
    ({"family": "rod", "grid": {"radius": [0.01]}, "list": [{"radius": 0.01}]}, "list"),
    ({"family": "rod"}, "grid"),
    ({"grid": {"radius": [0.01]}}, "family"),
    ({"family": "rod", "parameters": {"radius": 0.01}, "grid": {"radius": [0.02]}}, "grid.radius"),
    ({"family": "rod", "lhs": {"ranges": {"radius": [0.01, 0.02]}, "samples": 4}}, "lhs.seed"),
    ({"family": "rod", "lhs": {"ranges": {"radius": [0.02, 0.01]}, "samples": 4, "seed": 0}}, "lhs.ranges.radius"),
    ({"family": "rod", "lhs": {"ranges": {"radius": [0.01, 0.02]}, "samples": 4, "seed": 0, "sead": 1}}, "lhs.sead"),
    ({"family": "rod", "list": [{"radius": 0.01}], "order": 3}, "order"),
    ({"family": "rod", "list": {"set": []}}, "list.set"),
    ({"family": "rod", "list": [{"radius": 0.01}], "estimate_accuracy": "yes"}, "estimate_accuracy"),
])
def test_bad_spec_names_the_field(data, field):
    with pytest.raises(SpecError) as info:
        parse_spec(data, source="bad.toml")
    assert info.value.field == field
    assert "bad.toml" in str(info.value) and field in str(info.value)


def test_load_spec_names_the_file_and_field(tmp_path):
    path = tmp_path / "sweep.toml"
    path.write_text('family = "rod"\nmesh_size = 0.004\ncolour = "red"\n[grid]\nradius = [0.01]\n')
    with pytest.raises(SpecError) as info:
        load_spec(path)
    assert info.value.file == str(path) and info.value.field == "colour"
    path.write_text('family = "rod"\n[grid\n')
    with pytest.raises(SpecError, match="not valid TOML"):
        load_spec(path)


def test_unknown_family_and_bad_name_template_are_spec_errors(tmp_path):
    with pytest.raises(SpecError) as info:
        run_fake(parse_spec({"family": "rodd", "grid": {"radius": [0.01], "length": [0.04]}}), tmp_path / "c")
    assert info.value.field == "family"
    spec = parse_spec({"family": "rod", "name": "rod-{diameter}", "grid": {"radius": [0.01], "length": [0.04]}})
    with pytest.raises(SpecError) as info:
        run_fake(spec, tmp_path / "c")
    assert info.value.field == "name" and "diameter" in str(info.value)


def test_missing_catalogue_directory_is_a_catalogue_error(tmp_path):
    spec = parse_spec(spec_dict(grid={"radius": [0.01], "length": [0.04]}))
    with pytest.raises(CatalogueError):
        run_fake(spec, tmp_path / "no" / "such" / "cat.h5")


def test_design_options_are_design_segment_keywords_and_keyed_ones_entry_key_keywords():
    # The spec's design options are passed on by name: each must be a keyword of
    # design_segment, and those that change the numbers a keyword of entry_key too
    # (otherwise two different entries would share a key and resuming would skip one).
    import inspect

    from vertebra.designer import design_segment, entry_key
    from vertebra.designer.sweep import DESIGN_OPTIONS, FiniteElementDesigner

    design_keywords = inspect.signature(design_segment).parameters
    key_keywords = inspect.signature(entry_key).parameters
    for option in DESIGN_OPTIONS:
        assert design_keywords[option.name].default == option.default, option.name
        assert (option.name in key_keywords) == option.keyed, option.name
    [task] = expand(parse_spec(spec_dict(list=[{"radius": 0.01, "length": 0.04, "poisson_ratio": 0.3}])))
    designer = FiniteElementDesigner()
    task = replace(task, parameters=designer.canonical("rod", task.parameters))
    assert designer.key(task) == entry_key("rod", task.parameters, mesh_size=0.004, order=1)
    assert designer.key(replace(task, options={**task.options, "order": 2})) != designer.key(task)


CHECK_PINNING = """
import json, os, subprocess, sys
import numpy
from vertebra.designer.threads import THREAD_VARIABLES, blas_threads, pin_blas_threads
before = blas_threads()
pin_blas_threads()
child = subprocess.run([sys.executable, "-c", "import os; print(os.environ['OPENBLAS_NUM_THREADS'])"],
                       capture_output=True, text=True).stdout.strip()
print(json.dumps({"before": before, "after": blas_threads(), "child": child,
                  "variables": [os.environ[v] for v in THREAD_VARIABLES]}))
"""


def test_pin_blas_threads_overrides_the_environment_and_limits_loaded_blas():
    # A fresh interpreter whose parent asked for 2 threads: numpy's OpenBLAS loads with
    # 2; pin_blas_threads brings it to 1 and sets the variables its children inherit.
    import subprocess
    import sys

    environment = {**os.environ, "OMP_NUM_THREADS": "2", "OPENBLAS_NUM_THREADS": "2", "MKL_NUM_THREADS": "2"}
    result = subprocess.run([sys.executable, "-c", CHECK_PINNING], capture_output=True, text=True,
                            env=environment, timeout=120)
    assert result.returncode == 0, result.stderr
    seen = json.loads(result.stdout)
    assert (seen["before"], seen["after"]) == (2, 1), seen
    assert seen["variables"] == ["1", "1", "1"] and seen["child"] == "1"


def test_unknown_executor_and_scheduler_misuse_are_rejected():
    assert {"serial", "local", "dask"} <= set(EXECUTORS)
    with pytest.raises(OptionError):
        make_executor("slurm")
    with pytest.raises(OptionError):
        make_executor("local", scheduler="tcp://127.0.0.1:8786")
    with pytest.raises(OptionError):
        make_executor("local", workers=0)


# --------------------------------------------------------------------------- resume, duplicates

def test_resume_skips_done_work_and_rerun_does_nothing(tmp_path):
    catalogue = tmp_path / "cat.jsonl"
    spec = parse_spec(spec_dict(grid={"radius": [0.01, 0.02, 0.03], "length": [0.04, 0.05]},
                                name="rod-r{radius}-L{length}"))
    # a previous, interrupted run had done two of the six tasks
    plan = plan_sweep(spec, catalogue, store=JsonLinesStore, designer=FAKE)
    for task in plan.todo[:2]:
        fake_store(catalogue, fake_job(task))
    CALLS.clear()
    report = run_fake(spec, catalogue)
    assert sorted(CALLS) == [2, 3, 4, 5]
    assert len(report.completed) == 4 and len(report.skipped) == 2 and report.exit_code == 0
    assert sorted(stored_keys(catalogue)) == sorted(t.key for t in plan.todo)
    assert report.completed[0].name == "rod-r0.02-L0.04"
    CALLS.clear()
    again = run_fake(spec, catalogue)
    assert CALLS == [] and len(again.skipped) == 6 and not again.completed and again.exit_code == 0
    assert not failure_log_path(catalogue).exists()


def test_repeated_parameter_sets_run_once(tmp_path):
    spec = parse_spec(spec_dict(list=[{"radius": 0.01, "length": 0.04}, {"radius": 0.02, "length": 0.04},
                                      {"radius": 0.01, "length": 0.04}]))
    CALLS.clear()
    report = run_fake(spec, tmp_path / "cat.jsonl")
    assert sorted(CALLS) == [0, 1]
    assert [(t.index, first) for t, first in report.duplicates] == [(2, 0)]
    assert [row["status"] for row in report.status()] == ["done", "done", "duplicate"]


def test_dry_run_designs_nothing(tmp_path):
    spec = parse_spec(spec_dict(grid={"radius": [0.01, -0.02], "length": [0.04]}))
    CALLS.clear()
    report = run_fake(spec, tmp_path / "cat.jsonl", dry_run=True)
    assert CALLS == [] and len(report.todo) == 1 and len(report.failures) == 1 and report.exit_code == 1
    assert not (tmp_path / "cat.jsonl").exists() and not failure_log_path(tmp_path / "cat.jsonl").exists()


# --------------------------------------------------------------------------- failures

def test_failures_are_isolated_and_logged(tmp_path):
    catalogue = tmp_path / "cat.jsonl"
    spec = parse_spec(spec_dict(list=[{"radius": 0.01, "length": 0.04},
                                      {"radius": -0.01, "length": 0.04},             # invalid geometry
                                      {"radius": 0.02, "length": 0.04, "explode": True},
                                      {"radius": 0.03, "length": 0.04}]))
    CALLS.clear()
    report = run_fake(spec, catalogue)
    assert report.exit_code == 1
    assert sorted(CALLS) == [0, 2, 3]                       # the invalid task never reached the job
    assert [o.index for o in report.completed] == [0, 3]
    assert len(stored_keys(catalogue)) == 2
    lines = [json.loads(line) for line in failure_log_path(catalogue).read_text().splitlines()]
    assert [(r["index"], r["stage"], r["error_type"]) for r in sorted(lines, key=lambda r: r["index"])] == [
        (1, "validate", "GeometryError"), (2, "design", "RuntimeError")]
    by_index = {r["index"]: r for r in lines}
    assert by_index[1]["parameters"]["radius"] == -0.01 and "radius" in by_index[1]["message"]
    assert by_index[2]["message"] == "boom in task 2" and "RuntimeError" in by_index[2]["traceback"]
    assert by_index[2]["key"] and by_index[2]["parameters"]["explode"] is True
    assert not Path(str(failure_log_path(catalogue)) + ".lock").exists()     # the log's lock leaves nothing
    for record in lines:
        assert record["version"] == 1 and record["sweep"] == "<dict>" and record["catalogue"] == str(catalogue)
        assert record["family"] == "rod" and record["mesh_size"] == 0.004 and record["order"] == 1
    # a re-run retries the failed task only (the invalid one is re-reported, not run)
    CALLS.clear()
    again = run_fake(spec, catalogue)
    assert CALLS == [2] and again.exit_code == 1 and len(again.skipped) == 2


def test_local_pool_survives_a_dying_worker(tmp_path, monkeypatch):
    # Two spawned workers; task 0 kills its worker process, which breaks the pool
    # and fails every task then in flight. Those are re-run one at a time, so only
    # task 0 is reported (as a worker crash) and the seven others land.
    for variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        monkeypatch.setenv(variable, "4")              # the parent's setting must not reach the workers
    catalogue = tmp_path / "cat.jsonl"
    sets = [{"radius": 0.01, "length": 0.04, "crash": True}] + [
        {"radius": 0.01 * (i + 2), "length": 0.04} for i in range(7)]
    report = run_fake(parse_spec(spec_dict(list=sets)), catalogue, executor="local", workers=2)
    summary = report.summary()
    assert [(f.index, f.stage, f.error_type) for f in report.failures] == [(0, "worker", "WorkerCrashed")], summary
    assert [o.index for o in report.completed] == list(range(1, 8)), summary
    # A set, not a list: a task whose worker was terminated with the broken pool
    # after it had stored its entry but before its result came back is re-run and
    # stores again (the real catalogue's add_entry is idempotent; this fake appends).
    assert set(stored_keys(catalogue)) == {o.key for o in report.completed}, summary
    # the workers ran in other processes with BLAS/OpenMP pinned to one thread
    assert {o.worker["omp_num_threads"] for o in report.completed} == {"1"}
    # numpy is imported while a spawned worker starts (before its initializer runs),
    # so only the parent-side pinning makes OpenBLAS itself single-threaded
    assert {o.worker["blas_threads"] for o in report.completed} <= {1, None}
    assert all(o.worker["pid"] != os.getpid() for o in report.completed)
    assert report.exit_code == 1
    assert os.environ["OMP_NUM_THREADS"] == "4"       # and the parent's environment is restored


def test_serial_executor_turns_escaping_errors_into_crashes():
    with make_executor("serial") as executor:
        results = dict(executor.map_unordered(lambda x: 1 / x, [1, 0, 2]))
    assert results[1] == 1 and results[2] == 0.5
    assert isinstance(results[0], Crash) and results[0].error_type == "ZeroDivisionError"


def test_dask_runs_the_same_tasks_as_serial_and_isolates_failures(tmp_path, monkeypatch):
    # Same fake job on a dask LocalCluster (2 single-threaded worker processes):
    # the same keys land, the exploding task is reported with its worker traceback.
    monkeypatch.setenv("OMP_NUM_THREADS", "4")      # the workers must still get 1
    sets = [{"radius": 0.01 * (i + 1), "length": 0.04} for i in range(4)]
    sets[2]["explode"] = True
    spec = parse_spec(spec_dict(list=sets))
    serial = run_fake(spec, tmp_path / "serial.jsonl")
    dask = run_fake(spec, tmp_path / "dask.jsonl", executor="dask", workers=2)
    assert [o.key for o in dask.completed] == [o.key for o in serial.completed]
    assert [o.compliance for o in dask.completed] == [o.compliance for o in serial.completed]
    assert [(f.index, f.stage, f.error_type) for f in dask.failures] == [(2, "design", "RuntimeError")]
    assert "boom in task 2" in dask.failures[0].traceback
    assert {o.worker["omp_num_threads"] for o in dask.completed} == {"1"}
    assert dask.executor == {"name": "dask", "workers": 2}


def test_dask_executor_connects_to_a_running_scheduler(tmp_path):
    # --scheduler ADDRESS: the sweep is a client of a cluster it did not start.
    from dask.distributed import LocalCluster

    spec = parse_spec(spec_dict(grid={"radius": [0.01, 0.02], "length": [0.04]}))
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        report = run_fake(spec, tmp_path / "cat.jsonl", executor="dask", scheduler=cluster.scheduler_address)
    assert report.exit_code == 0 and len(report.completed) == 2
    assert report.executor == {"name": "dask", "workers": 1, "scheduler": cluster.scheduler_address}
    assert sorted(stored_keys(tmp_path / "cat.jsonl")) == sorted(o.key for o in report.completed)


def test_workers_fill_the_real_hdf5_catalogue_and_resume_skips(tmp_path):
    # Fake (cheap) job, real store: two spawned workers write their own entries
    # concurrently with catalogue.add_entry; the catalogue verifies, every entry
    # round-trips, and a re-run finds everything via catalogue.has_entry.
    designer = FakeDesigner(known=None)
    path = tmp_path / "cat.h5"
    spec = parse_spec(spec_dict(grid={"radius": [0.01, 0.02, 0.03], "length": [0.04, 0.05]}, name="f-{index}"))
    report = run_sweep(spec, path, executor="local", workers=2, designer=designer, progress=False)
    assert report.exit_code == 0 and len(report.completed) == 6
    assert catalogue.verify(path) == []
    with catalogue.open_catalogue(path) as cat:
        assert sorted(row["key"] for row in cat.list()) == sorted(o.key for o in report.completed)
        for outcome in report.completed:
            assert np.array_equal(cat.load(outcome.key).compliance, np.array(outcome.compliance))
    # both ways of asking the store agree: all keys in one read, and has_entry per key
    for store in (CatalogueStore, CatalogueAskedPerKey):
        CALLS.clear()
        again = run_sweep(spec, path, executor="serial", store=store, designer=designer, progress=False)
        assert CALLS == [] and len(again.skipped) == 6 and again.exit_code == 0


class CatalogueAskedPerKey(CatalogueStore):
    """The HDF5 store without its one-read key listing: planning asks ``has_entry`` per key."""

    def keys(self):
        return None


def interrupting_job(task):
    if task.index == 2:
        raise KeyboardInterrupt
    return fake_job(task)


def test_ctrl_c_keeps_what_landed_and_a_rerun_resumes(tmp_path):
    catalogue = tmp_path / "cat.jsonl"
    spec = parse_spec(spec_dict(grid={"radius": [0.01, 0.02, 0.03, 0.04], "length": [0.04]}))
    interrupted = run_sweep(spec, catalogue, executor="serial", progress=False, store=JsonLinesStore,
                            designer=FakeDesigner(job=interrupting_job))
    assert interrupted.interrupted and interrupted.exit_code == 130
    assert [o.index for o in interrupted.completed] == [0, 1]
    assert [row["status"] for row in interrupted.status()] == ["done", "done", "not run", "not run"]
    CALLS.clear()
    resumed = run_fake(spec, catalogue)
    assert sorted(CALLS) == [2, 3] and len(resumed.skipped) == 2 and resumed.exit_code == 0


def test_forkserver_start_method_runs_tasks_and_fork_is_refused(tmp_path):
    spec = parse_spec(spec_dict(grid={"radius": [0.01, 0.02, 0.03], "length": [0.04]}))
    report = run_fake(spec, tmp_path / "cat.jsonl", executor="local", workers=2, start_method="forkserver")
    assert report.exit_code == 0 and len(report.completed) == 3
    assert {o.worker["omp_num_threads"] for o in report.completed} == {"1"}
    assert report.executor == {"name": "local", "workers": 2, "start_method": "forkserver"}
    with pytest.raises(OptionError) as info:
        make_executor("local", start_method="fork")     # gmsh's global state must not be forked
    assert info.value.field == "start_method"


def test_progress_bar_goes_to_stderr_only(tmp_path, capsys):
    spec = parse_spec(spec_dict(grid={"radius": [0.01, 0.02], "length": [0.04]}))
    run_sweep(spec, tmp_path / "cat.jsonl", executor="serial", store=JsonLinesStore, designer=FAKE, progress=True)
    captured = capsys.readouterr()
    assert captured.out == ""                       # stdout stays clean for --json
    assert "sweep rod" in captured.err and "2/2" in captured.err


ACTIVE = []


def overlap_detecting_job(task):
    """Fails if another job runs in this process at the same time (as two gmsh models would)."""
    import time as _time

    ACTIVE.append(task.index)
    try:
        _time.sleep(0.05)
        if len(ACTIVE) > 1:
            raise RuntimeError(f"jobs {ACTIVE} ran at once in one process")
        return fake_job(task)
    finally:
        ACTIVE.remove(task.index)


def test_multithreaded_dask_worker_runs_one_job_at_a_time(tmp_path):
    # A cluster started by someone else with 2 threads per worker process: the
    # sweep's process-wide lock makes the tasks take turns (gmsh is not
    # thread-safe). Without the lock the 50 ms jobs would overlap and fail.
    from dask.distributed import LocalCluster

    spec = parse_spec(spec_dict(grid={"radius": [0.01, 0.02, 0.03, 0.04], "length": [0.04]}))
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=True, dashboard_address=None) as cluster:
        report = run_sweep(spec, tmp_path / "cat.jsonl", executor="dask", scheduler=cluster.scheduler_address,
                           store=JsonLinesStore, designer=FakeDesigner(job=overlap_detecting_job), progress=False)
    assert report.exit_code == 0, report.summary()
    assert len(report.completed) == 4 and len({o.worker["pid"] for o in report.completed}) == 1


def drifting_job(task):
    """An entry whose key is not the one planned (as when the designer's code changes mid-sweep)."""
    entry = fake_job(task)
    return SegmentEntry(**{**entry.__dict__, "key": content_key({"other": task.index})})


def test_a_stored_key_other_than_the_planned_one_is_a_failure(tmp_path):
    # The entry lands, but under a key that resume would never find: reported
    # (stage "store", KeyMismatch, naming both keys) and exit code 1.
    spec = parse_spec(spec_dict(grid={"radius": [0.01], "length": [0.04]}))
    planned = plan_sweep(spec, tmp_path / "cat.jsonl", store=JsonLinesStore, designer=FAKE).todo[0].key
    report = run_sweep(spec, tmp_path / "cat.jsonl", executor="serial", progress=False, store=JsonLinesStore,
                       designer=FakeDesigner(job=drifting_job))
    [failure] = report.failures
    assert (failure.stage, failure.error_type) == ("store", "KeyMismatch") and report.exit_code == 1
    stored = stored_keys(tmp_path / "cat.jsonl")
    assert stored == [content_key({"other": 0})] and planned in failure.message and stored[0] in failure.message


def test_a_script_without_a_main_guard_is_told_why_its_workers_die(tmp_path):
    # spawned workers import the main script again; one that starts a pool at import time makes
    # every worker fail while it starts: the crash says so instead of only "segmentation fault"
    import subprocess
    import sys

    script = tmp_path / "unguarded.py"
    script.write_text("import math\n"
                      "from vertebra.designer.executors import make_executor\n"
                      "with make_executor('local', workers=1) as pool:\n"
                      "    for _, result in pool.map_unordered(math.sqrt, [4.0]):\n"
                      "        print(getattr(result, 'message', result))\n")
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert "if __name__ == \"__main__\":" in out.stdout, out.stdout + out.stderr[-2000:]
