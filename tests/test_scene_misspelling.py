"""Misspelt scene fields are reported as misspellings of the field meant, before any required
field is reported missing; fields that are merely unknown are still named as unknown."""

import pytest

from vertebra import solver
from vertebra.cli.main import main
from vertebra.core.errors import SceneError

BEAM = {"type": "beam", "count": 2, "length": 0.02, "youngs_modulus": 54e9, "poisson_ratio": 0.3,
        "section": {"shape": "circle", "radius": 7e-4}}


def renamed(table: dict, old: str, new: str) -> dict:
    return {(new if k == old else k): v for k, v in table.items()}


@pytest.mark.parametrize("data,field,meant", [
    # a misspelt required field: reported as unknown (with the field meant), not as missing
    ({"segment": [renamed(BEAM, "youngs_modulus", "youngs_modulous")]}, "segment[0].youngs_modulous",
     "youngs_modulus"),
    ({"segment": [renamed(BEAM, "length", "lenght")]}, "segment[0].lenght", "length"),
    ({"segment": [renamed(BEAM, "section", "sectoin")]}, "segment[0].sectoin", "section"),
    ({"segment": [dict(BEAM, section={"shape": "circle", "radus": 1e-3})]}, "segment[0].section.radus", "radius"),
    # a misspelt optional field read before the missing required one (shape decides which is required)
    ({"segment": [dict(BEAM, section={"shap": "circle", "radius": 1e-3})]}, "segment[0].section.shap", "shape"),
    # misspelt optional fields, found when the table is done
    ({"segment": [dict(BEAM, densty=1000.0)]}, "segment[0].densty", "density"),
    ({"segment": [BEAM], "cable": [{"name": "t", "radius": 0.01, "to": 2, "max_tensoin": 3.0}]},
     "cable[0].max_tensoin", "max_tension"),
    ({"segment": [BEAM], "gravity": {"vectr": [0.0, 0.0, -9.81]}}, "gravity.vectr", "vector"),
    # a misspelt table is reported before its absence makes anything else look missing
    ({"segment": [BEAM], "solvr": {"tolerance": 1e-6}}, "solvr", "solver"),
    ({"segment": [dict(BEAM, vertbra={"mass": 0.01})]}, "segment[0].vertbra", "vertebra"),
])
def test_misspelt_fields_name_the_field_meant(data, field, meant):
    with pytest.raises(SceneError) as caught:
        solver.parse_scene(data, source="s.toml")
    error = caught.value
    assert error.field == field
    typed = field.rpartition(".")[2]
    assert error.reason == f"unknown field `{typed}`, did you mean `{meant}`?"


@pytest.mark.parametrize("data,field,reason", [
    # nothing like a misspelling: a missing field stays missing, an unknown one stays unknown
    ({"segment": [{k: v for k, v in BEAM.items() if k != "length"}]}, "segment[0].length", "required field is missing"),
    ({"segment": [dict(BEAM, colour="red")]}, "segment[0].colour", "unknown field"),
    # distinct fields of one table are not each other's misspellings
    ({"segment": [dict(BEAM, section={"shape": "tube", "inner_radius": 1e-3})]}, "segment[0].section.outer_radius",
     "required field is missing"),
    # a field given twice under near names: the real one is read, the other is unknown without a guess
    ({"segment": [dict(BEAM, density=1.0, densty=2.0)]}, "segment[0].densty", "unknown field"),
])
def test_missing_and_unknown_fields_without_a_guess(data, field, reason):
    with pytest.raises(SceneError) as caught:
        solver.parse_scene(data, source="s.toml")
    assert caught.value.field == field and caught.value.reason == reason


def test_cli_reports_the_misspelling(tmp_path, capsys):
    path = tmp_path / "typo.toml"
    path.write_text('[[segment]]\ntype = "beam"\nlength = 0.1\nyoungs_modulous = 1e9\n'
                    'section = { shape = "circle", radius = 0.001 }\n')
    assert main(["simulate", str(path)]) == 2
    err = capsys.readouterr().err
    assert "typo.toml: segment[0].youngs_modulous: unknown field `youngs_modulous`, did you mean `youngs_modulus`?" in err
