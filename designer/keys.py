"""What identifies a segment design: its inputs resolved (:class:`SegmentDesign`) and the content
key of its catalogue entry, computed without meshing (the same for ``vertebra design``, a sweep
and a scene's design segments)."""

from __future__ import annotations

import dataclasses
import functools
from importlib import metadata

from vertebra.core.errors import GeometryError, OptionError
from vertebra.designer.energy_sampling import SamplingSettings
from vertebra.designer.families import Family, canonical_parameters, family_of, resolve_mesh_size
from vertebra.designer.multifidelity import choose_nonlinear_mesh
from vertebra.designer.nonlinear.materials import MATERIALS
from vertebra.store.entry import content_key

#: bump when a change in designer/ changes the numbers of an entry (part of the key)
ALGORITHM_VERSION = "designer-4"   # 4: P1 accuracy by raising the order; Richardson size ratio by edge lengths
#: bump when a change in the nonlinear FE, the sampling or the fit changes a nonlinear entry's ψ
NONLINEAR_VERSION = "nonlinear-1"
#: the materials of ``design_segment``: ``linear`` (small strain, the condensation alone) and the
#: hyperelastic models of designer.nonlinear (an energy ψ(s, p) is sampled and fitted)
LINEAR = "linear"
#: layout of the key payload
KEY_SCHEMA = 1


def package_version(distribution: str) -> str:
    """The installed version of ``distribution`` ("unknown" when it is not installed)."""
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        return "unknown"


@functools.lru_cache(maxsize=1)
def _result_versions() -> tuple:
    return (("gmsh", package_version("gmsh")), ("scikit-fem", package_version("scikit-fem")),
            ("algorithm", ALGORITHM_VERSION), ("key_schema", KEY_SCHEMA))


def result_versions() -> dict:
    """Versions that change the numbers of an entry (part of the content key); package
    metadata is read once per process (planning a 10k-task sweep asks 10k times)."""
    return dict(_result_versions())


def check_material(material: str) -> str:
    if material != LINEAR and material not in MATERIALS:
        raise OptionError(f"unknown material {material!r} (known: {', '.join(sorted(set(MATERIALS) | {LINEAR}))})",
                          field="material")
    return material


def sampling_settings(sampling=None) -> SamplingSettings:
    """``designer.energy_sampling.SamplingSettings`` from None (defaults), a dict or settings."""
    return sampling if isinstance(sampling, SamplingSettings) else SamplingSettings.from_dict(sampling)


def key_payload(family, parameters: dict, *, mesh_size=None, order: int = 2, material: str = LINEAR,
                sampling=None) -> dict:
    """What the content key hashes. A nonlinear material adds ``material`` and ``nonlinear``
    (the sampling and fit settings and the nonlinear algorithm version); a linear entry's
    payload (and key) is the same as before nonlinear entries existed. Above
    ``designer.multifidelity.AUTO_DOFS`` the nonlinear mesh chosen is part of the settings."""
    fam = family_of(family)
    p = canonical_parameters(fam, parameters)
    if order not in (1, 2):
        raise GeometryError(f"parameter 'order': must be 1 or 2, got {order!r}")
    h = resolve_mesh_size(fam, p, mesh_size)
    payload = {"family": fam.name, "parameters": p, "mesh": {"mesh_size": h, "order": int(order)},
               "versions": result_versions()}
    if check_material(material) != LINEAR:
        payload["material"] = material
        settings = choose_nonlinear_mesh(fam, p, h, order, sampling_settings(sampling))
        settings = settings.resolved(fam.n_cavities(p), material)
        payload["nonlinear"] = {"sampling": settings.describe(), "version": NONLINEAR_VERSION}
    return payload


def entry_key(family, parameters: dict, *, mesh_size=None, order: int = 2, material: str = LINEAR,
              sampling=None) -> str:
    """Content key of the entry WITHOUT meshing (store.content_key of the key payload)."""
    return content_key(key_payload(family, parameters, mesh_size=mesh_size, order=order, material=material,
                                   sampling=sampling))


@dataclasses.dataclass(frozen=True)
class SegmentDesign:
    """One segment design, resolved (:meth:`resolve`): what a condenser needs to make its entry.

    ``parameters``: canonical; ``sampling``: the nonlinear sampling and fit settings (None for
    ``linear``); ``started``: ``time.perf_counter()`` when the design began (an entry's
    ``total_s`` counts from there); ``warnings``: messages the entry's ``accuracy`` records."""

    family: Family
    parameters: dict
    mesh_size: float
    order: int
    material: str
    sampling: SamplingSettings | None
    key: str
    name: str
    started: float
    warnings: tuple[str, ...] = ()

    @property
    def nonlinear(self) -> bool:
        return self.material != LINEAR

    @classmethod
    def resolve(cls, family, parameters: dict, *, mesh_size=None, order: int = 2, material: str = LINEAR,
                sampling=None, name: str | None = None, started: float) -> "SegmentDesign":
        """Family looked up, parameters validated, mesh size and settings resolved, key computed
        (GeometryError or OptionError before any meshing)."""
        fam = family_of(family)
        p = canonical_parameters(fam, parameters)
        h = resolve_mesh_size(fam, p, mesh_size)
        check_material(material)
        settings = sampling_settings(sampling) if material != LINEAR else None
        if settings is not None:
            settings = choose_nonlinear_mesh(fam, p, h, order, settings)
        coarse = settings.nonlinear_mesh_size if settings is not None else None
        if coarse is not None and not coarse > h:
            raise OptionError(f"{coarse!r} m is not coarser than the entry's mesh (mesh size {h!r} m): the "
                              f"nonlinear part is sampled on a coarser mesh of the same segment",
                              field="sampling.nonlinear_mesh_size")
        key = entry_key(fam, p, mesh_size=h, order=order, material=material, sampling=settings)
        return cls(family=fam, parameters=p, mesh_size=h, order=order, material=material, sampling=settings,
                   key=key, name=name or f"{fam.name}-{key[:8]}", started=started)
