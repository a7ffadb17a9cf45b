"""``vertebra invert`` text output: which steps were not reached, by index and time."""

from __future__ import annotations

import json

import numpy as np

from vertebra import solver
from vertebra.cli.invert import outcome
from vertebra.cli.main import main
from vertebra.solver.gallery import load, path
from vertebra.solver.inverse.trajectory import Trajectory, read_trajectory, write_trajectory


def _document(errors, times, tolerance=1e-3, equilibrium=None):
    """An invert document (the fields ``outcome`` reads) for per-step tip ``errors``."""
    equilibrium = equilibrium or [True] * len(errors)
    unreached = [{"step": i, "t": t, "effector": "tip", "error": e}
                 for i, (t, e) in enumerate(zip(times, errors)) if e > tolerance]
    return {"steps": [{"t": t, "equilibrium": ok} for t, ok in zip(times, equilibrium)],
            "unreached": unreached, "reached": not unreached and all(equilibrium)}


def test_outcome_names_steps_and_times():
    doc = _document([1e-4, 2e-3, 1e-4, 5e-3], [0.0, 0.25, 0.5, 0.75])
    line = outcome(doc, 1e-3, timed=True)
    assert line == ("NOT reached within 0.001 m at 2 of 4 steps: step 1 (t = 0.25 s): tip 2.000e-03 m; "
                    "step 3 (t = 0.75 s): tip 5.000e-03 m")
    # a trajectory without a t column counts steps only
    assert outcome(doc, 1e-3, timed=False).startswith("NOT reached within 0.001 m at 2 of 4 steps: step 1: tip")
    assert outcome(_document([1e-4] * 3, [0, 1, 2]), 1e-3, timed=True) == "reached within 0.001 m at every one of 3 steps"


def test_outcome_counts_what_it_does_not_name_and_equilibrium_failures():
    doc = _document([1.0] * 8, list(range(8)))
    line = outcome(doc, 1e-3, timed=False)
    assert "at 8 of 8 steps" in line and "step 4: tip" in line and "step 5:" not in line and line.endswith("and 3 more")
    failed = _document([1e-4, 1e-4], [0.0, 1.0], equilibrium=[True, False])
    assert outcome(failed, 1e-3, timed=True) == "NOT reached: no equilibrium at step 1 (t = 1 s)"


def test_tick_mode_text_names_the_step_not_reached(tmp_path, capsys):
    # two targets from forward solutions with an unreachable one (8 cm sideways at 3 cm height
    # on a 6 cm robot) between them: the text names step 1 and its time
    model = solver.build_model(load("paper_3v_4t"))
    near = [model.effector_positions(model.solve(np.array(a)).state)[0]
            for a in ([0.2, 0.0, 0.0, 0.1], [0.3, 0.0, 0.0, 0.1])]
    targets = np.array([near[0], [0.08, 0.0, 0.03], near[1]])[:, None, :]
    csv = tmp_path / "path.csv"
    write_trajectory(csv, Trajectory(targets, np.array([0.0, 0.5, 1.0])), ["tip"])
    assert read_trajectory(csv, ["tip"]).timed
    code = main(["invert", str(path("paper_3v_4t")), "--trajectory", str(csv), "--mode", "tick"])
    out = capsys.readouterr().out
    assert code == 1
    assert "NOT reached within 0.001 m at " in out and "step 1 (t = 0.5 s): tip" in out
    # the JSON names the same step, with its time
    code = main(["invert", str(path("paper_3v_4t")), "--trajectory", str(csv), "--mode", "tick", "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert {"step": 1, "t": 0.5} == {k: doc["unreached"][0][k] for k in ("step", "t")}
