"""Seeded tampering of nonlinear catalogue entries with the checksum recomputed, shared by
tests/test_catalogue_trust.py (every kind once or twice) and benchmarks/bench_catalogue_fuzz.py
(``--tamper`` cases).

A checksum is a plain SHA-256 that anyone with write access can recompute: it proves an entry
is what its writer stored, not that the writer stored something sound. Each case takes a sound
entry with a fitted energy (a P1 rod and a P1 pneumatic segment with the synthetic fits of
tests/fitted_energies.py, their provenance marking them as nonlinear designs), changes its
numbers the way a hostile or careless writer could — coefficients ×1e300 or ×(−1e3), a
non-convex quartic that contradicts the fit's recorded convexity, scales ×1e-100, a range of
±1e300 or one that excludes rest, thousands of extra terms, the energy group deleted — and
writes it with the ordinary writer, which computes a valid checksum and index row over the
tampered data. Then every reader must refuse the entry: ``verify`` reports it and ``load``
(what show, simulate, workspace and merge call) raises. ``accepted`` counts the cases where a
reader took it: it must be 0.
"""

from __future__ import annotations

import copy
import dataclasses
import warnings
from pathlib import Path

import numpy as np

KINDS = ("coefficients x1e300", "coefficients x(-1e3)", "non-convex quartic", "scales x1e-100",
         "scales x1e100", "range +-1e300", "range excludes rest", "extra terms", "duplicate terms",
         "energy deleted", "load range x1e6")


@dataclasses.dataclass
class Bases:
    rod: object
    pneumatic: object


def bases() -> Bases:
    """The two sound nonlinear entries the cases tamper with (~1 s)."""
    from vertebra import designer
    from fitted_energies import with_energy

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")           # order-1 locking warnings: not the point here
        rod = designer.design_segment("rod", dict(radius=0.01, length=0.04, youngs_modulus=1e6, poisson_ratio=0.3),
                                      mesh_size=0.01, order=1, estimate_accuracy=False, name="tamper-rod")
        pneumatic = designer.design_segment(
            "pneumatic", dict(outer_radius=0.02, chamber_radius=0.005, chamber_offset=0.011, length=0.02,
                              youngs_modulus=1e6, poisson_ratio=0.45), mesh_size=0.008, order=1,
            estimate_accuracy=False, name="tamper-pneumatic")
    out = []
    for entry in (rod, pneumatic):
        nl = with_energy(entry)
        fit = _raw_replace(nl.energy, fit_error={**nl.energy.fit_error, "convexity_min_relative_eigenvalue": 0.5})
        nl = _raw_replace(nl, energy=fit, provenance={**nl.provenance, "nonlinear": {"version": "synthetic"}})
        nl = dataclasses.replace(nl)               # through the constructor: the base is sound
        out.append(nl)
    return Bases(*out)


def _raw_replace(obj, **changes):
    """A copy of a frozen dataclass with ``changes``, without running its checks: what a writer
    that bypasses vertebra's constructors stores."""
    new = copy.copy(obj)
    for name, value in changes.items():
        object.__setattr__(new, name, value)
    return new


def tamper(entry, kind: str, rng: np.random.Generator):
    """``entry`` changed by ``kind`` (one of :data:`KINDS`), its checks bypassed."""
    from vertebra.core.energy import monomial_exponents

    fit = entry.energy
    r = fit.range
    nv = fit.scales.size
    if kind == "coefficients x1e300":
        return _raw_replace(entry, energy=_raw_replace(fit, coefficients=fit.coefficients * 10.0 ** rng.integers(8, 301)))
    if kind == "coefficients x(-1e3)":
        factor = -(10.0 ** rng.uniform(1, 3))     # × −1 of a weak correction stays convex: not detectable
        return _raw_replace(entry, energy=_raw_replace(fit, coefficients=fit.coefficients * factor))
    if kind == "non-convex quartic":
        j = int(rng.integers(0, 6))
        quartic = np.flatnonzero((fit.exponents[:, j] == 4) & (fit.exponents.sum(1) == 4))[0]
        coefficients = fit.coefficients.copy()
        coefficients[quartic] = -abs(coefficients).max() * 10.0 ** rng.uniform(2, 4)
        return _raw_replace(entry, energy=_raw_replace(fit, coefficients=coefficients))
    if kind in ("scales x1e-100", "scales x1e100"):
        scales = fit.scales.copy()
        j = int(rng.integers(0, 6))
        exponent = rng.integers(3, 101)
        scales[j] *= 10.0 ** (-exponent if kind == "scales x1e-100" else exponent)
        return _raw_replace(entry, energy=_raw_replace(fit, scales=scales))
    if kind == "range +-1e300":
        big = 10.0 ** rng.integers(4, 301)
        field = ("pose", "load")[int(rng.integers(0, 2))]
        new_range = _raw_replace(r, **{f"{field}_lower": np.where(getattr(r, f"{field}_lower") < 0, -big, 0.0),
                                       f"{field}_upper": np.full(4, big)})
        return _raw_replace(entry, energy=_raw_replace(fit, range=new_range))
    if kind == "load range x1e6":
        factor = 10.0 ** rng.uniform(4, 8)
        new_range = _raw_replace(r, load_lower=r.load_lower * factor, load_upper=r.load_upper * factor)
        return _raw_replace(entry, energy=_raw_replace(fit, range=new_range))
    if kind == "range excludes rest":
        lower = r.pose_lower.copy()
        group = (1, 3)[int(rng.integers(0, 2))]             # a signed group: axial or twist
        lower[group] = rng.uniform(0.1, 0.9) * r.pose_upper[group]
        return _raw_replace(entry, energy=_raw_replace(fit, range=_raw_replace(r, pose_lower=lower)))
    if kind == "extra terms":
        top = int(rng.integers(11, 13))
        extra = monomial_exponents(nv, top, 5) if nv == 6 else monomial_exponents(nv, 11, 11)
        known = {tuple(row) for row in fit.exponents}
        extra = np.array([row for row in extra if tuple(row) not in known], dtype=np.int64)
        exponents = np.concatenate([fit.exponents, extra])
        coefficients = np.concatenate([fit.coefficients, np.zeros(len(extra))])
        return _raw_replace(entry, energy=_raw_replace(fit, exponents=exponents, coefficients=coefficients))
    if kind == "duplicate terms":
        rows = rng.integers(0, fit.exponents.shape[0], size=int(rng.integers(1, 50)))
        exponents = np.concatenate([fit.exponents, fit.exponents[rows]])
        coefficients = np.concatenate([fit.coefficients, np.zeros(rows.size)])
        return _raw_replace(entry, energy=_raw_replace(fit, exponents=exponents, coefficients=coefficients))
    if kind == "energy deleted":
        return _raw_replace(entry, energy=None)
    raise ValueError(kind)


def write_resigned(path: Path, entry) -> None:
    """A catalogue file holding ``entry`` exactly, with its checksum, content digest and index
    row computed over it (no soundness check on the way)."""
    import h5py

    from vertebra.store import schema

    enc = object.__new__(schema.EncodedEntry)
    enc.entry, enc.key, enc.name, enc.family, enc.mass = entry, entry.key, entry.name, entry.family, float(entry.mass)
    enc.arrays = {f: np.ascontiguousarray(getattr(entry, f), dtype="<f8") for f in schema.ARRAY_FIELDS}
    enc.dicts = {f: schema.to_jsonable(getattr(entry, f), f) for f in schema.DICT_FIELDS}
    enc.checksum, enc.content = schema.digests(enc.key, enc.name, enc.family, enc.mass, enc.arrays, enc.dicts,
                                               entry.energy)
    with h5py.File(path, "w") as f:
        schema.init_file(f)
        schema.write_entry(f["entries"], enc)
        schema.append_index(f, [enc.index_row()])


def readers(path: Path, key: str) -> dict:
    """What each reader did with the entry: ``refused`` or ``accepted``."""
    from vertebra.core.errors import CatalogueError
    from vertebra.store import catalogue

    out = {"verify": "refused" if catalogue.verify(path) else "accepted"}
    try:
        with catalogue.open_catalogue(path) as cat:
            cat.load(key)
        out["load"] = "accepted"
    except CatalogueError:
        out["load"] = "refused"
    return out


def run(directory: Path, seeds, base: Bases | None = None) -> list[dict]:
    """One case per seed (kind = seed mod the number of kinds, base entry alternating)."""
    base = base or bases()
    directory = Path(directory)
    results = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        kind = KINDS[seed % len(KINDS)]
        entry = (base.rod, base.pneumatic)[(seed // len(KINDS)) % 2]
        bad = tamper(entry, kind, rng)
        path = directory / f"tamper-{seed}.h5"
        write_resigned(path, bad)
        results.append({"seed": seed, "kind": kind, "entry": entry.name, **readers(path, bad.key)})
        path.unlink()
    return results
