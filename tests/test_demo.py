"""`make demo` runs `vertebra demo`: the whole pipeline must keep working end to end
(scikit-fem examples-as-tests habit). Coarse meshes: ~20 s."""

import json

from vertebra.cli.main import main


def test_demo_runs_the_whole_pipeline(tmp_path, capsys):
    code = main(["demo", "--out", str(tmp_path), "--points", "6"])
    out = capsys.readouterr().out
    assert code == 0, out
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert all(value == 0 for key, value in summary.items() if key != "total_s")
    for picture in ("tendon_forward.png", "cbha_forward.png", "tendon_inverse.png", "cbha_inverse.png",
                    "cbha_circle.png"):
        assert (tmp_path / picture).stat().st_size > 10_000
    tracking = json.loads((tmp_path / "cbha_circle.json").read_text())
    assert tracking["reached"] is True
    assert all(0.0 <= c["pressure"] <= 1.5e5 for step in tracking["steps"] for c in step["chambers"].values())
