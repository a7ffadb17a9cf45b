"""Bounds a forward solve breaks are reported (solver/bounds.py), a pushing cable is refused, and
the JSON documents hold standard JSON only (non-finite numbers as null; a refused solve still
prints its document)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vertebra import solver
from vertebra.cli.main import main
from vertebra.cli.outputs import finite_json, write_json
from vertebra.core.errors import OptionError, SceneError
from vertebra.solver.bounds import BoundViolation, bound_violations
from vertebra.solver.report import static_report
from vertebra.solver.scene import scene_toml


def _strict(text: str):
    """``json.loads`` that refuses the non-standard tokens NaN, Infinity and -Infinity."""
    def refuse(token):
        raise ValueError(f"non-standard JSON token {token}")
    return json.loads(text, parse_constant=refuse)


def robot(**cable) -> dict:
    """A two-tendon rod (10 vertebrae 20 mm apart, nitinol r = 0.7 mm); ``cable`` overrides the
    first tendon's fields."""
    first = {"name": "t1", "radius": 0.008, "angle_deg": 0.0, "from": 1, "to": 10, "tension": 1.0,
             "min_tension": 0.0, "max_tension": 15.0, "min_stroke": -0.03, **cable}
    return {"name": "two-tendon rod",
            "segment": [{"type": "beam", "count": 10, "length": 0.02, "elements": 2, "youngs_modulus": 54e9,
                         "poisson_ratio": 0.33, "section": {"shape": "circle", "radius": 0.0007}}],
            "cable": [first, {"name": "t2", "radius": 0.008, "angle_deg": 180.0, "from": 1, "to": 10,
                              "tension": 0.0, "max_tension": 15.0}],
            "effector": [{"name": "tip", "vertebra": -1}]}


def test_a_forward_solve_reports_the_bounds_it_breaks():
    model = solver.build_model(solver.parse_scene(robot(min_stroke=-0.004)))
    assert model.solve().bound_violations == ()
    result = model.solve({"t1": 40.0})                   # max_tension 15 N; the pull shortens its path
    assert result.converged
    tension, stroke = result.bound_violations
    assert (tension.actuator, tension.quantity, tension.bound, tension.limit, tension.value, tension.excess) == \
        ("t1", "tension", "max_tension", 15.0, 40.0, 25.0)
    path = model.actuator_displacements(result.state, result.actuation)[0]
    assert path < -0.004
    assert (stroke.quantity, stroke.bound, stroke.limit) == ("stroke", "min_stroke", -0.004)
    assert stroke.value == path and stroke.excess == pytest.approx(-0.004 - path, rel=1e-12)
    assert str(tension) == "t1: tension 40 N is 25 N above its max_tension 15 N"
    assert bound_violations(model, result.state, result.actuation) == result.bound_violations
    rows = static_report(model, result)["diagnostics"]["bound_violations"]
    assert rows[0] == {"actuator": "t1", "quantity": "tension", "bound": "max_tension", "limit": 15.0, "value": 40.0,
                       "excess": 25.0, "unit": "N"}
    assert [row["quantity"] for row in rows] == ["tension", "stroke"]


def test_a_stroke_driven_tendon_reports_its_tension_and_its_servo_stroke():
    tendon = dict(tension=None, stroke=0.002, stiffness=4000.0, max_tension=3.0, min_stroke=0.0, max_stroke=0.004)
    tendon = {k: v for k, v in tendon.items() if v is not None}
    data = robot()
    data["cable"][0] = {k: v for k, v in {**data["cable"][0], **tendon}.items() if k != "tension"}
    model = solver.build_model(solver.parse_scene(data))
    result = model.solve({"t1": 0.006})               # 6 mm of servo stroke at 4 N/mm: beyond 3 N and 4 mm
    tension = model.cable_tensions(result.state, result.actuation)[0]
    assert tension > 3.0
    found = {(v.quantity, v.bound): v for v in result.bound_violations}
    assert set(found) == {("servo stroke", "max_stroke"), ("tension", "max_tension")}
    assert found["servo stroke", "max_stroke"].excess == pytest.approx(0.002, rel=1e-12)
    assert found["tension", "max_tension"].value == tension
    assert found["tension", "max_tension"].excess == pytest.approx(tension - 3.0, rel=1e-12)


def test_a_cable_does_not_push_unless_the_scene_says_it_may():
    model = solver.build_model(solver.parse_scene(robot()))
    with pytest.raises(OptionError, match="cable 't1' would push with a tension of -5 N"):
        model.solve({"t1": -5.0})
    with pytest.raises(SceneError, match=r"cable\[0\]\.tension"):
        solver.build_model(solver.parse_scene(robot(tension=-5.0))).solve()
    rod = solver.build_model(solver.parse_scene(robot(min_tension=-10.0)))          # a push–pull actuator
    assert rod.solve({"t1": -5.0}).converged and rod.solve({"t1": -5.0}).bound_violations == ()


def test_simulate_warns_and_its_json_is_standard(tmp_path, capsys):
    path = tmp_path / "rod.toml"
    path.write_text(scene_toml(robot(tension=40.0)))
    assert main(["simulate", str(path), "--json"]) == 0
    captured = capsys.readouterr()
    document = _strict(captured.out)
    assert document["diagnostics"]["bound_violations"][0]["bound"] == "max_tension"
    assert "beyond the scene's bounds" in captured.err and "t1: tension 40 N is 25 N above" in captured.err
    path.write_text(scene_toml(robot(tension=-5.0)))
    assert main(["simulate", str(path), "--json"]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and "would push" in captured.err


def test_non_finite_numbers_are_written_as_null(capsys):
    document = {"a": float("inf"), "b": [1.0, float("nan"), {"c": -float("inf")}], "d": "text", "e": 2}
    assert finite_json(document) == {"a": None, "b": [1.0, None, {"c": None}], "d": "text", "e": 2}
    write_json(document)
    assert _strict(capsys.readouterr().out) == finite_json(document)
    assert str(BoundViolation("c0", "pressure", "max_pressure", 1e5, 1.5e5, 5e4)) == \
        "c0: pressure 150000 Pa is 50000 Pa above its max_pressure 100000 Pa"


def test_a_refused_solve_prints_its_document(tmp_path, capsys):
    # a chamber pressurised beyond its entry's fold pressure has no state to report: exit 1, and
    # under --json a document that says why
    from fitted_energies import with_energy
    from test_solver_fitted import SLICE

    from vertebra.store import catalogue

    entry = with_energy(SLICE, strength=0.3, pressure=1.0e5, fold_pressure=1.3e5)
    catalogue.add_entry(tmp_path / "cat.h5", entry)
    data = {"name": "pressed", "catalogue": {"path": "cat.h5"},
            "segment": [{"type": "entry", "entry": entry.name, "count": 2}],
            "chamber": [{"name": "c0", "cavity": 0, "from": 1, "to": 2, "pressure": 1.35e5, "max_pressure": 1.4e5}],
            "effector": [{"name": "tip", "vertebra": -1}]}
    (tmp_path / "scene.toml").write_text(scene_toml(data))
    assert main(["simulate", str(tmp_path / "scene.toml"), "--json"]) == 1
    captured = capsys.readouterr()
    document = _strict(captured.out)
    assert document["converged"] is False and document["scene"] == "pressed"
    assert document["error"]["type"] == "ConvergenceError"
    assert "fold pressure of its fitted energy's pressure map" in document["error"]["message"]
    assert "vertebra_version" in document
