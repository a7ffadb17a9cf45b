"""``vertebra catalogue`` as a person reads it: listings cut nothing, a mistyped condition is an
error naming it, and every JSON document names the vertebra version that printed it."""

from __future__ import annotations

import json

import pytest

from vertebra import __version__
from vertebra.store import catalogue
from test_catalogue import make_entry, vertebra

LONG = "a-segment-name-longer-than-any-column-width-of-the-old-listing"


@pytest.fixture
def rods(tmp_path):
    """Four rods (radius varies, index varies, the rest shared) and one bellows."""
    path = tmp_path / "c.h5"
    entries = [make_entry(i, family="rod", name=f"{LONG}-{i}",
                          parameters={"radius": 0.001 * (i + 1), "length": 0.04, "index": i,
                                      "material": {"youngs_modulus": 1e6, "poisson_ratio": 0.45},
                                      "description": "x" * 80})
               for i in range(4)]
    entries.append(make_entry(9, family="bellows"))
    catalogue.add_entries(path, entries)
    return path, entries


def test_ls_shows_varied_parameters_in_full_and_shared_ones_once(rods, monkeypatch, capsys):
    path, entries = rods
    code, out, _ = vertebra(["ls", path], monkeypatch, capsys)
    assert code == 0
    lines = out.splitlines()
    assert lines[0].split()[:6] == ["key", "name", "family", "cav", "material", "parameters"]
    for e in entries[:4]:
        row = next(line for line in lines if line.startswith(e.key))
        # nothing cut: the whole key and name, and every varied parameter with its value
        assert f"{e.name} " in row and "…" not in row
        assert row.endswith(f"index={e.parameters['index']}, radius={e.parameters['radius']}")
    shared = [line for line in lines if line.startswith("every rod entry: ")]
    assert shared == ['every rod entry: description="' + "x" * 80 + '", length=0.04, '
                      'material={"poisson_ratio": 0.45, "youngs_modulus": 1000000.0}']
    # a family of one entry shows all its parameters on its row
    bellows = next(line for line in lines if line.startswith(entries[4].key))
    assert "radius=" in bellows and "material=" in bellows


def test_ls_wide_shows_every_parameter_on_every_row(rods, monkeypatch, capsys):
    path, entries = rods
    code, out, _ = vertebra(["ls", path, "--wide"], monkeypatch, capsys)
    assert code == 0 and "every rod entry" not in out
    row = next(line for line in out.splitlines() if line.startswith(entries[0].key))
    assert row.endswith('description="' + "x" * 80 + '", index=0, length=0.04, '
                        'material={"poisson_ratio": 0.45, "youngs_modulus": 1000000.0}, radius=0.001')


@pytest.mark.parametrize("condition", ["radius>>1", "radius>=", "radius=<1", "radius<>1", "radius!"])
def test_query_with_a_mistyped_operator_exits_2_naming_the_condition(rods, monkeypatch, capsys, condition):
    path, _ = rods
    code, out, err = vertebra(["query", path, "--where", condition], monkeypatch, capsys)
    assert code == 2 and out == ""
    assert f"condition {condition!r}" in err or f"cannot parse condition {condition!r}" in err


def test_query_values_that_start_like_an_operator_can_be_quoted(rods, monkeypatch, capsys):
    path, entries = rods
    code, out, _ = vertebra(["query", path, "--where", "name!='>x'", "--json"], monkeypatch, capsys)
    assert code == 0 and len(json.loads(out)) == len(entries)
    code, out, _ = vertebra(["query", path, "--where", "radius>0.0025", "--where", "family=rod", "--wide"],
                            monkeypatch, capsys)
    assert code == 0 and [line.split()[0] for line in out.splitlines()[1:]] == [e.key for e in entries[2:4]]


def test_every_catalogue_json_document_names_the_version(rods, tmp_path, monkeypatch, capsys):
    path, entries = rods
    for argv in (["ls", path], ["query", path, "--where", "family=rod"]):
        code, out, _ = vertebra([*argv, "--json"], monkeypatch, capsys)
        rows = json.loads(out)
        assert code == 0 and rows and all(r["vertebra_version"] == __version__ for r in rows)
    for argv in (["show", path, entries[0].key, "--json"], ["verify", path, "--json"],
                 ["export", path, entries[0].key], ["merge", tmp_path / "m.h5", path, "--json"],
                 ["consolidate", path, "--json"]):
        code, out, _ = vertebra(argv, monkeypatch, capsys)
        assert code == 0 and json.loads(out)["vertebra_version"] == __version__, argv
    # an exported entry with the version field still reads back
    code, out, _ = vertebra(["export", path, entries[0].key], monkeypatch, capsys)
    assert catalogue.entry_from_dict(json.loads(out)).key == entries[0].key
