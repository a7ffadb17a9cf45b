"""Catalogue file format, API and CLI (issues 3 and 5, DESIGN.md §6).

Arrays must round-trip bit for bit (HDF5 float64 datasets store IEEE doubles as-is),
so array comparisons here are exact, not toleranced.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from vertebra import __version__ as vertebra_version
from vertebra.store import catalogue, schema, shards
from vertebra.store.entry import SegmentEntry
from vertebra.core.errors import CatalogueError

ROOT = Path(__file__).resolve().parents[1]


def make_entry(i: int, n_cavities: int = 1, seed: int = 0, **over) -> SegmentEntry:
    """A small random entry with an SPD compliance (seeded: same i and seed → same entry)."""
    rng = np.random.default_rng([seed, i, n_cavities])
    m = 6 + n_cavities
    a = rng.normal(size=(m, m))
    compliance = a @ a.T + m * np.eye(m)
    kw = dict(key=f"{seed:04x}{i:016x}", name=f"seg-{seed}-{i}", family="rod" if i % 2 else "bellows",
              parameters={"radius": 0.005 * (1 + i % 7), "length": 0.04, "index": i,
                          "material": {"youngs_modulus": 1e6, "poisson_ratio": 0.45}},
              compliance=compliance, cavity_volumes=rng.random(n_cavities) * 1e-6,
              mass=float(rng.random()), center_of_mass=rng.normal(size=3),
              rest_translation=[0.0, 0.0, 0.04], rest_quaternion=[1.0, 0.0, 0.0, 0.0],
              mesh={"order": 2, "size": 0.002, "dofs": 1234 + i},
              accuracy={"relative_change": 1e-3 * rng.random(), "method": "refined mesh"},
              timings={"mesh_s": 0.1, "total_s": 1.5},
              provenance={"gmsh": "4.15.2", "host": "test", "date": "2026-11-22"})
    kw.update(over)
    return SegmentEntry(**kw)


def assert_same_entry(a: SegmentEntry, b: SegmentEntry) -> None:
    for field in ("key", "name", "family", "parameters", "mesh", "accuracy", "timings", "provenance"):
        assert getattr(a, field) == getattr(b, field), field
    assert type(b.mass) is float and a.mass == b.mass
    for field in schema.ARRAY_FIELDS:
        x, y = getattr(a, field), getattr(b, field)
        assert x.shape == y.shape and x.dtype == y.dtype and x.tobytes() == y.tobytes(), field


@pytest.fixture
def cat3(tmp_path):
    path = tmp_path / "cat.h5"
    entries = [make_entry(i, n_cavities=i % 3) for i in range(3)]
    for e in entries:
        catalogue.add_entry(path, e)
    return path, entries


# ---------------------------------------------------------------- round trip and layout

def test_round_trip_every_field_bit_exact(tmp_path):
    path = tmp_path / "c.h5"
    entries = [make_entry(0, n_cavities=0), make_entry(1, n_cavities=3),
               make_entry(2, n_cavities=1, rest_quaternion=[np.cos(0.3), 0, np.sin(0.3), 0],
                          parameters={"radius": 1 / 3, "tiny": 5e-324, "neg_zero": -0.0, "big": 2**70,
                                      "flag": True, "none": None, "list": [1, 2.5, "x"], "unicode": "µm²"})]
    for e in entries:
        assert catalogue.add_entry(path, e) == e.key
    with catalogue.open_catalogue(path) as cat:
        assert sorted(cat.keys()) == sorted(e.key for e in entries)
        for e in entries:
            assert_same_entry(e, cat.load(e.key))
    assert catalogue.verify(path) == []


def test_file_is_plain_hdf5_with_documented_layout(cat3):
    path, entries = cat3
    with h5py.File(path, "r") as f:
        assert f.attrs["schema_version"] == 1      # linear entries only: still readable as version 1
        assert f.attrs["format"].decode() == "vertebra-catalogue"
        g = f["entries"][entries[1].key]
        assert g["compliance"].dtype == np.float64 and g["compliance"].shape == (7, 7)
        assert json.loads(g.attrs["parameters"].decode()) == entries[1].parameters
        assert g.attrs["checksum"].decode().startswith("sha256:")
        rows = [json.loads(s) for s in f["index"].asstr()[()]]
        assert [r["key"] for r in rows] == [e.key for e in entries]


def test_lazy_open_lists_without_reading_entries(cat3, monkeypatch):
    """Corrupting one entry's data must not affect opening, listing or loading others:
    proof that only the index is read on open and only the loaded entry on load."""
    path, entries = cat3
    _flip_byte_in_dataset(path, entries[0].key, "compliance")
    calls = []
    real = schema.read_entry
    monkeypatch.setattr("vertebra.store.catalogue.read_entry", lambda *a: calls.append(a[1]) or real(*a))
    with catalogue.open_catalogue(path) as cat:
        rows = cat.list()
        assert calls == []
        assert [r["name"] for r in rows] == [e.name for e in entries]
        assert set(rows[0]) >= {"key", "name", "family", "parameters"}
        assert_same_entry(entries[2], cat.load(entries[2].key))
        assert calls == [entries[2].key]
        with pytest.raises(CatalogueError, match="checksum mismatch"):
            cat.load(entries[0].key)


def test_load_by_key_prefix_or_name_and_clear_errors(tmp_path):
    path = tmp_path / "c.h5"
    a = make_entry(1, key="abcd0001", name="twin")
    b = make_entry(2, key="abcd0002", name="twin")
    c = make_entry(3, key="ffff0003", name="solo")
    for e in (a, b, c):
        catalogue.add_entry(path, e)
    with catalogue.open_catalogue(path) as cat:
        assert cat.load("solo").key == c.key
        assert cat.load("ffff").key == c.key                 # unique prefix
        assert cat.load("abcd0002").key == b.key
        with pytest.raises(CatalogueError, match=r"c\.h5.*name 'twin' is ambiguous"):
            cat.load("twin")
        with pytest.raises(CatalogueError, match="prefix 'abcd' is ambiguous"):
            cat.load("abcd")
        with pytest.raises(CatalogueError, match=r"c\.h5: no entry .*'nope'"):
            cat.load("nope")
        with pytest.raises(CatalogueError, match="no entry"):
            cat.load("fff")                                   # prefixes need ≥ 4 characters


@pytest.mark.parametrize("over, match", [
    ({"key": "../evil"}, "invalid entry key"),
    ({"key": "a/b"}, "invalid entry key"),
    ({"key": ".hidden"}, "invalid entry key"),
    ({"name": "x/../y"}, "path separators"),
    ({"name": "bad\nname"}, "control characters"),
    ({"parameters": {"r": float("nan")}}, "not finite"),
    ({"parameters": {1: 2}}, "not a string"),
    ({"mesh": {"s": {1, 2}}}, "not JSON data"),
])
def test_unsafe_keys_names_and_metadata_are_refused(tmp_path, over, match):
    path = tmp_path / "c.h5"
    with pytest.raises(CatalogueError, match=match):
        catalogue.add_entry(path, make_entry(0, **over))
    assert not path.exists() and not list(shards.list_shards(path))


def test_numpy_values_in_metadata_are_stored_as_plain_json(tmp_path):
    path = tmp_path / "c.h5"
    e = make_entry(0, parameters={"radius": np.float64(0.01), "count": np.int64(3), "v": np.arange(2.0)})
    catalogue.add_entry(path, e)
    with catalogue.open_catalogue(path) as cat:
        assert cat.load(e.key).parameters == {"radius": 0.01, "count": 3, "v": [0.0, 1.0]}


def test_add_is_idempotent_and_refuses_conflicts(cat3):
    path, entries = cat3
    e = entries[1]
    again = make_entry(1, n_cavities=1, timings={"total_s": 99.0}, provenance={"host": "elsewhere"})
    assert catalogue.add_entry(path, again) == e.key             # timings/provenance do not count
    before = path.read_bytes()
    other = make_entry(1, n_cavities=1, seed=0, mass=e.mass + 1.0)
    with pytest.raises(CatalogueError, match=rf"{e.key} already exists with different content \(mass\)"):
        catalogue.add_entry(path, other)
    assert path.read_bytes() == before
    with catalogue.open_catalogue(path) as cat:
        assert len(cat) == 3
        assert_same_entry(e, cat.load(e.key))
    assert catalogue.has_entry(path, e.key) and not catalogue.has_entry(path, "0123456789")


def test_pending_shards_are_visible_then_consolidated(tmp_path):
    path = tmp_path / "c.h5"
    catalogue.add_entry(path, make_entry(0))
    late = [make_entry(i) for i in (1, 2)]
    catalogue.add_entry(path, late[0], consolidate=False)
    catalogue.add_entries(path, [late[1]], consolidate=False)
    assert len(shards.list_shards(path)) == 2
    assert catalogue.has_entry(path, late[0].key) and catalogue.has_entry(path, late[1].key)
    with catalogue.open_catalogue(path) as cat:
        assert sorted(cat.pending) == sorted(e.key for e in late)
        assert_same_entry(late[1], cat.load(late[1].name))
    assert catalogue.verify(path) == []
    report = catalogue.consolidate(path)
    assert sorted(report.added) == sorted(e.key for e in late)
    assert shards.list_shards(path) == []
    with catalogue.open_catalogue(path) as cat:
        assert cat.pending == [] and len(cat) == 3


def test_corrupt_pending_shard_is_set_aside(tmp_path):
    path = tmp_path / "c.h5"
    catalogue.add_entry(path, make_entry(0))
    catalogue.add_entry(path, make_entry(1), consolidate=False)
    shard = shards.list_shards(path)[0]
    _flip_byte_in_dataset(shard, make_entry(1).key, "compliance")
    report = catalogue.consolidate(path)
    assert report.added == [] and len(report.rejected) == 1 and "checksum mismatch" in report.rejected[0]
    problems = catalogue.verify(path)
    assert len(problems) == 1 and problems[0].endswith("inspect and delete it")
    with catalogue.open_catalogue(path) as cat:
        assert cat.keys() == [make_entry(0).key]


def test_remove(cat3):
    path, entries = cat3
    assert catalogue.remove(path, entries[1].name) == entries[1].key
    with catalogue.open_catalogue(path) as cat:
        assert cat.keys() == [entries[0].key, entries[2].key]
    with h5py.File(path, "r") as f:
        assert entries[1].key not in f["entries"]
    assert catalogue.verify(path) == []
    with pytest.raises(CatalogueError, match="no entry"):
        catalogue.remove(path, entries[1].key)


# ---------------------------------------------------------------- merge

def test_merge_adds_skips_identical_reports_conflicts_and_is_idempotent(tmp_path):
    a, b, out = tmp_path / "a.h5", tmp_path / "b.h5", tmp_path / "out.h5"
    for i in range(3):
        catalogue.add_entry(a, make_entry(i))
    catalogue.add_entry(b, make_entry(2, timings={"total_s": 7.0}))          # same content
    catalogue.add_entry(b, make_entry(3))
    conflicting = make_entry(1, seed=0, compliance=2 * make_entry(1).compliance)
    catalogue.add_entry(b, conflicting)
    report = catalogue.merge(out, [a, b])
    keys = [make_entry(i).key for i in range(4)]
    assert sorted(report.added) == sorted(keys)
    assert report.skipped == [keys[2]]
    assert [(c.key, c.source, c.fields) for c in report.conflicts] == [(keys[1], str(b), ["compliance"])]
    with catalogue.open_catalogue(out) as cat:
        assert_same_entry(make_entry(1), cat.load(keys[1]))                  # nothing overwritten
        assert len(cat) == 4
    again = catalogue.merge(out, [a, b])
    assert again.added == [] and sorted(again.skipped) == sorted(keys[:3] + [keys[2], keys[3]])
    assert len(again.conflicts) == 1
    assert catalogue.verify(out) == []


def test_merge_refuses_a_corrupt_input_and_writes_nothing(tmp_path):
    a, b, out = tmp_path / "a.h5", tmp_path / "b.h5", tmp_path / "out.h5"
    catalogue.add_entry(a, make_entry(0))
    catalogue.add_entry(b, make_entry(1))
    _flip_byte_in_dataset(b, make_entry(1).key, "center_of_mass")
    with pytest.raises(CatalogueError, match="checksum mismatch"):
        catalogue.merge(out, [a, b])
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []


# ---------------------------------------------------------------- corrupted and foreign files

def _flip_byte_in_dataset(path, key, field):
    with h5py.File(path, "r") as f:
        ds = f["entries"][key][field]
        offset = ds.id.get_offset()
        assert offset is not None
    with open(path, "r+b") as fh:
        fh.seek(offset + 3)
        byte = fh.read(1)
        fh.seek(offset + 3)
        fh.write(bytes([byte[0] ^ 0x10]))


def test_bit_flip_in_a_dataset_is_caught_by_checksum(cat3):
    path, entries = cat3
    _flip_byte_in_dataset(path, entries[1].key, "compliance")
    with catalogue.open_catalogue(path) as cat:
        with pytest.raises(CatalogueError, match=rf"cat\.h5: entry {entries[1].key} .*checksum mismatch"):
            cat.load(entries[1].key)
        assert_same_entry(entries[0], cat.load(entries[0].key))
    problems = catalogue.verify(path)
    assert len(problems) == 1 and entries[1].key in problems[0] and "checksum mismatch" in problems[0]


def test_edited_metadata_is_caught(cat3):
    path, entries = cat3
    with h5py.File(path, "r+") as f:     # an outside tool editing in place (never done by vertebra)
        f["entries"][entries[0].key].attrs["parameters"] = np.bytes_(b'{"radius":1.0}')
    with pytest.raises(CatalogueError, match="checksum mismatch"):
        catalogue.open_catalogue(path).load(entries[0].key)
    assert any("checksum mismatch" in p for p in catalogue.verify(path))


def test_truncated_file(cat3, tmp_path):
    path, _ = cat3
    bad = tmp_path / "truncated.h5"
    data = path.read_bytes()
    bad.write_bytes(data[: len(data) // 2])
    for call in (catalogue.open_catalogue, catalogue.verify):
        with pytest.raises(CatalogueError, match=r"truncated\.h5: unreadable HDF5 file \(truncated or corrupt\)"):
            call(bad)


def test_wrong_schema_version(cat3):
    path, _ = cat3
    with h5py.File(path, "r+") as f:
        f.attrs["schema_version"] = np.int64(schema.SCHEMA_VERSION + 1)
    with pytest.raises(CatalogueError, match=f"schema version {schema.SCHEMA_VERSION + 1} is newer than this vertebra understands"):
        catalogue.open_catalogue(path)
    with pytest.raises(CatalogueError, match="newer"):
        catalogue.add_entry(path, make_entry(9))       # the merger refuses to build on it
    with pytest.raises(CatalogueError, match="newer"):
        catalogue.verify(path)


@pytest.mark.parametrize("content, match", [
    (b"", r"empty file \(0 bytes\)"),
    (b"key,name\n1,rod\n" * 50, "not an HDF5 file"),
])
def test_empty_and_non_hdf5_files(tmp_path, content, match):
    path = tmp_path / "c.h5"
    path.write_bytes(content)
    for call in (catalogue.open_catalogue, catalogue.verify):
        with pytest.raises(CatalogueError, match=rf"c\.h5: {match}"):
            call(path)
    with pytest.raises(CatalogueError, match=match):
        catalogue.add_entry(path, make_entry(0))
    assert path.read_bytes() == content


def test_foreign_hdf5_and_missing_file(tmp_path):
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "x") as f:
        f["data"] = np.arange(3)
    with pytest.raises(CatalogueError, match="not a vertebra catalogue"):
        catalogue.open_catalogue(foreign)
    with pytest.raises(CatalogueError, match=r"missing\.h5: no such catalogue file"):
        catalogue.open_catalogue(tmp_path / "missing.h5")


def test_store_never_opens_hdf5_with_mode_w():
    """Field notes: mode 'w' left a 0-byte file while another process read it."""
    for source in (ROOT / "store").glob("*.py"):
        text = source.read_text()
        assert not re.search(r"""h5py\.File\([^)]*["']w["']""", text), source
        assert not re.search(r"""h5open\([^)]*["']w["']""", text), source
    with pytest.raises(ValueError, match="not 'w'"):
        shards.h5open("/nonexistent/x.h5", "w")


# ---------------------------------------------------------------- query and export

def test_query_operators(tmp_path):
    path = tmp_path / "c.h5"
    entries = [make_entry(i) for i in range(8)]
    catalogue.add_entries(path, entries)

    def keys(*where):
        return sorted(r["key"] for r in catalogue.query(path, list(where)))

    expect = lambda pred: sorted(e.key for e in entries if pred(e))  # noqa: E731
    assert keys("radius>=0.02") == expect(lambda e: e.parameters["radius"] >= 0.02)
    assert keys("radius<0.02", "family=rod") == expect(
        lambda e: e.parameters["radius"] < 0.02 and e.family == "rod")
    assert keys("family!=rod") == expect(lambda e: e.family != "rod")
    assert keys("index > 5") == expect(lambda e: e.parameters["index"] > 5)
    assert keys("index<=1") == expect(lambda e: e.parameters["index"] <= 1)
    assert keys("material.poisson_ratio=0.45") == expect(lambda e: True)
    assert keys("name='seg-0-3'") == [entries[3].key]
    with pytest.raises(CatalogueError, match="cannot parse condition"):
        catalogue.query(path, ["radius ~ 3"])
    with pytest.raises(CatalogueError, match="no entry .* has a field 'radiuss'"):
        catalogue.query(path, ["radiuss>1"])


def test_export_json_and_npz_round_trip(cat3, tmp_path):
    path, entries = cat3
    e = entries[2]
    out_json = catalogue.export(path, e.key, "json", tmp_path / "e.json")
    assert_same_entry(e, catalogue.entry_from_dict(json.loads(out_json.read_text())))
    out_npz = catalogue.export(path, e.name, "npz", tmp_path / "e.npz")
    assert_same_entry(e, catalogue.entry_from_npz(out_npz))
    with np.load(out_npz, allow_pickle=False) as z:       # plain arrays, no pickled objects
        assert z["compliance"].shape == e.compliance.shape
    with pytest.raises(CatalogueError, match="format 'csv' unknown"):
        catalogue.export(path, e.key, "csv", tmp_path / "e.csv")


# ---------------------------------------------------------------- CLI

def vertebra(argv, monkeypatch, capsys):
    """``vertebra catalogue ...`` through cli.main (only our subcommand registered)."""
    from vertebra.cli import main as cli_main

    monkeypatch.setattr(cli_main, "SUBCOMMANDS", {"catalogue": cli_main.SUBCOMMANDS["catalogue"]})
    code = cli_main.main(["catalogue", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_ls_show_query_export_rm(cat3, tmp_path, monkeypatch, capsys):
    path, entries = cat3
    code, out, _ = vertebra(["ls", path, "--json"], monkeypatch, capsys)
    assert code == 0
    assert json.loads(out) == [{"vertebra_version": vertebra_version, "key": e.key, "name": e.name,
                                "family": e.family, "parameters": e.parameters} for e in entries]
    code, out, _ = vertebra(["show", path, entries[1].name, "--json"], monkeypatch, capsys)
    assert code == 0 and json.loads(out)["compliance"] == entries[1].compliance.tolist()
    code, out, _ = vertebra(["query", path, "--where", "family=rod", "--json"], monkeypatch, capsys)
    assert code == 0 and [r["key"] for r in json.loads(out)] == [entries[1].key]
    code, out, _ = vertebra(["export", path, entries[0].key], monkeypatch, capsys)
    assert code == 0 and json.loads(out)["key"] == entries[0].key
    code, out, _ = vertebra(["export", path, entries[0].key, "--format", "npz", "--out", tmp_path / "x.npz"],
                            monkeypatch, capsys)
    assert code == 0 and out == "" and (tmp_path / "x.npz").exists()
    code, out, err = vertebra(["show", path, "nope"], monkeypatch, capsys)
    assert code == 2 and out == "" and "no entry" in err
    code, _, _ = vertebra(["rm", path, entries[0].key], monkeypatch, capsys)
    assert code == 0
    code, out, _ = vertebra(["ls", path, "--json"], monkeypatch, capsys)
    assert len(json.loads(out)) == 2


def test_cli_verify_and_merge_exit_codes(cat3, tmp_path, monkeypatch, capsys):
    path, entries = cat3
    code, out, _ = vertebra(["verify", path], monkeypatch, capsys)
    assert code == 0 and out == ""
    other = tmp_path / "other.h5"
    catalogue.add_entry(other, make_entry(0, mass=123.0, n_cavities=0))
    code, out, err = vertebra(["merge", tmp_path / "m.h5", path, other, "--json"], monkeypatch, capsys)
    assert code == 1 and json.loads(out)["conflicts"][0]["fields"] == ["mass"]
    flipped = tmp_path / "flipped.h5"
    shutil.copy(path, flipped)
    _flip_byte_in_dataset(flipped, entries[2].key, "cavity_volumes")
    code, out, _ = vertebra(["verify", flipped], monkeypatch, capsys)
    assert code == 2 and "checksum mismatch" in out
    text = tmp_path / "notes.h5"
    text.write_text("hello")
    code, out, err = vertebra(["verify", text], monkeypatch, capsys)
    assert code == 2 and out == "" and "not an HDF5 file" in err
    code, _, err = vertebra(["ls", tmp_path / "absent.h5"], monkeypatch, capsys)
    assert code == 2 and "no such catalogue file" in err


# ---------------------------------------------------------------- less common paths

def test_reader_survives_a_merge_between_open_and_load(tmp_path):
    path = tmp_path / "c.h5"
    catalogue.add_entry(path, make_entry(0))
    late = [make_entry(1), make_entry(2)]
    catalogue.add_entries(path, late, consolidate=False)          # one batch shard of two
    assert [p.name.split("@")[0] for p in shards.list_shards(path)] == ["batch"]
    assert all(catalogue.has_entry(path, e.key) for e in late)
    with catalogue.open_catalogue(path) as cat:
        assert sorted(cat.pending) == sorted(e.key for e in late)
        catalogue.consolidate(path)                              # shard merged and deleted
        assert shards.list_shards(path) == []
        assert_same_entry(late[1], cat.load(late[1].key))        # found in the new file
    with catalogue.open_catalogue(path) as cat:
        assert cat.pending == [] and len(cat) == 3


def test_lock_timeout_leaves_the_entry_committed(tmp_path, caplog):
    path = tmp_path / "c.h5"
    catalogue.add_entry(path, make_entry(0))
    with shards.catalogue_lock(path, timeout=1):                  # another merger is busy
        key = catalogue.add_entry(path, make_entry(1), timeout=0.2)
        assert "stays committed as a shard" in caplog.text
        with catalogue.open_catalogue(path) as cat:
            assert key in cat.pending
            assert_same_entry(make_entry(1), cat.load(key))
    catalogue.add_entry(path, make_entry(2))                      # next writer merges both
    with catalogue.open_catalogue(path) as cat:
        assert cat.pending == [] and len(cat) == 3


def test_index_and_entries_disagreeing_is_reported(cat3):
    path, entries = cat3
    with h5py.File(path, "r+") as f:                              # an outside tool deleting a group
        del f["entries"][entries[0].key]
    with catalogue.open_catalogue(path) as cat:
        with pytest.raises(CatalogueError, match="entry group is missing"):
            cat.load(entries[0].key)
    problems = catalogue.verify(path)
    assert problems == [f"{path}: index lists {entries[0].key} but there is no such entry group"]


def test_same_key_pending_with_different_content_is_refused(tmp_path):
    path = tmp_path / "c.h5"
    catalogue.add_entry(path, make_entry(0), consolidate=False)
    with pytest.raises(CatalogueError, match=r"already exists with different content \(mass\)"):
        catalogue.add_entry(path, make_entry(0, mass=42.0))
    assert len(shards.list_shards(path)) == 1


def test_cli_verify_prints_problems_of_a_broken_index(cat3, monkeypatch, capsys):
    path, _ = cat3
    with h5py.File(path, "r+") as f:                              # garbage appended to the index
        f["index"].resize((4,))
        f["index"][3] = "{not json"
    code, out, _ = vertebra(["verify", path], monkeypatch, capsys)
    assert code == 2 and "invalid JSON" in out
