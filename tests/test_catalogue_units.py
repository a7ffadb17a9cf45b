"""HDF5 datasets carry ``units`` and ``description`` attributes (for h5dump and HDFView users);
files written without them still read and verify."""

from __future__ import annotations

import shutil

import h5py
import numpy as np

from vertebra.store import catalogue, schema
from test_catalogue import make_entry


def _datasets(path) -> dict:
    found = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: found.__setitem__(name, dict(obj.attrs))
                     if isinstance(obj, h5py.Dataset) else None)
    return found


def test_every_dataset_has_units_and_a_description(tmp_path):
    path = tmp_path / "c.h5"
    catalogue.add_entries(path, [make_entry(i, n_cavities=i) for i in range(3)])
    datasets = _datasets(path)
    assert len(datasets) == 1 + 3 * len(schema.ARRAY_FIELDS)            # the index and every entry's arrays
    for name, attrs in datasets.items():
        field = name.rpartition("/")[2]
        units, description = schema.DATASET_ATTRIBUTES[field]
        assert attrs["units"].decode() == units and attrs["description"].decode() == description, name
    compliance_units = schema.DATASET_ATTRIBUTES["compliance"][0]
    assert compliance_units == "[[m/N, 1/N, m/Pa], [rad/N, rad/(N m), rad/Pa], [m^3/N, m^2/N, m^3/Pa]]"
    # fixed-length strings, as every other attribute vertebra writes
    with h5py.File(path, "r") as f:
        key = next(iter(f["entries"]))
        assert f["entries"][key]["compliance"].attrs.get_id("units").dtype.kind == "S"
    assert catalogue.verify(path) == []


def test_a_file_without_the_attributes_still_reads_and_verifies(tmp_path):
    path = tmp_path / "c.h5"
    entries = [make_entry(i, n_cavities=1) for i in range(2)]
    catalogue.add_entries(path, entries)
    bare = tmp_path / "bare.h5"
    shutil.copy(path, bare)
    with h5py.File(bare, "r+") as f:          # a copy, as an older vertebra wrote it
        for name in list(_datasets(path)):
            for attribute in ("units", "description"):
                del f[name].attrs[attribute]
    assert all("units" not in attrs for attrs in _datasets(bare).values())
    assert catalogue.verify(bare) == []
    with catalogue.open_catalogue(bare) as cat:
        loaded = cat.load(entries[1].key)
    assert np.array_equal(loaded.compliance, entries[1].compliance)
