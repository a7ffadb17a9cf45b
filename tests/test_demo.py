"""`make demo` runs `vertebra demo`: the whole pipeline must keep working end to end
(scikit-fem examples-as-tests habit). Coarse meshes: ~20 s."""

import json

import pytest

from vertebra.cli.main import main
from vtk_xml import read_pvd, read_vtp


@pytest.mark.slow
def test_demo_runs_the_whole_pipeline(tmp_path, capsys):
    code = main(["demo", "--out", str(tmp_path), "--points", "6"])
    out = capsys.readouterr().out
    assert code == 0, out
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert all(value == 0 for key, value in summary.items() if key != "total_s")
    for picture in ("tendon_forward.png", "cbha_forward.png", "tendon_inverse.png", "cbha_inverse.png",
                    "cbha_circle.png"):
        assert (tmp_path / picture).stat().st_size > 10_000
    # the ParaView files: a .vtp of the forward shape, a .pvd of the 6-step circle, the frames CSV
    forward = read_vtp(tmp_path / "tendon_forward.vtp")
    assert forward.field_data["cable_names"][0] == "s1-0" and len(forward.points) > 41
    series = read_pvd(tmp_path / "tendon_inverse.pvd")
    assert len(series) == 6 and all(len(read_vtp(f).cells["lines"]) > 10 for _, f in series)
    assert len((tmp_path / "tendon_forward_frames.csv").read_text().splitlines()) == 1 + 41
    tracking = json.loads((tmp_path / "cbha_circle.json").read_text())
    assert tracking["reached"] is True
    assert all(0.0 <= c["pressure"] <= 1.5e5 for step in tracking["steps"] for c in step["chambers"].values())
