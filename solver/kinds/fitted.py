"""Catalogue entries with a fitted energy (nonlinear entries, catalogue schema v2) as links.

An entry designed with a nonlinear material stores its segment's energy ``ψ(s, p)`` as a
function of the strain ``s = ξ − ξ₀`` of its end frames and of its cavity pressures ``p``
(:mod:`vertebra.core.energy`; docs/nonlinear-condensation.md): because the vertebrae are rigid, that energy is the
segment's whole response, and a chain of such links is the full nonlinear model of the trunk up
to the fit. Each repetition of the segment makes one link that stores ψ itself:

    ψ_link(ξ, p_chambers) = ψ(ξ − ξ₀, M p_chambers)

where ``M`` (cavities × chambers, 0/1) says which chamber pressurises which cavity of the link
(chambers map onto cavities as for quadratic links: a cavity served by two chambers carries the
sum of their pressures). The entry's rest rotation is the identity, so ``ξ₀ = [d₀; 0]`` is the
fit's rest strain. The kernel (:class:`~vertebra.core.energy.EnergyModel`, one call per distinct
entry and evaluation, batched over its links) gives every derivative the runtime consumes:

* ``w = ∂ψ/∂s`` and the material tangent ``∂²ψ/∂s²`` (kept from the same call: ``response``
  evaluates once, the tangent reuses it);
* the chamber forces ``−∂²ψ/∂s∂p · M`` and the volume growth ``−(∂ψ/∂p) · M`` summed over the
  links, so the chambers' actuator Jacobian columns and displacements follow ψ's own pressure
  dependence (the ballooning a linear cavity Jacobian misses).

The energy includes its pressure terms, so the total potential that Newton and the inverse's
tick acceptance judge is the right one. At small strains and pressures ψ is the linear entry's
quadratic energy plus terms of degree ≥ 3: the links reproduce the linear entry's.

Range. The fit is trusted where it was sampled; :meth:`FittedEnergy.out_of_range` reports every
quantity of a state (group coordinates of the strain and of the load, cavity pressures) outside
the entry's ``EnergyRange`` — a result's diagnostics, never a silent extrapolation. A pressure at
or beyond the inflation limit point (the fold of the fitted volume, or the limit met while
sampling) has no equilibrium near it, and the fit cannot be evaluated at or beyond its fold
pressure: such a load case is refused with a ConvergenceError that says which of the two it met.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from vertebra.core.energy import EnergyModel, EnergyValues, FixedPressures
from vertebra.core.errors import ConvergenceError
from vertebra.solver.kinds import CompiledLinks, LinkSource, RangeExcess, refuse_scaled_cavities, register
from vertebra.solver.kinds.entry import entry_link


@dataclass(frozen=True)
class FittedEntry:
    """What a link of a nonlinear entry keeps of the entry: its name and key, and its compiled
    energy (:class:`~vertebra.core.energy.EnergyModel`, built once per entry)."""

    name: str
    key: str
    model: EnergyModel


@dataclass(frozen=True)
class _Group:
    """The links of one entry within a batch: rows of the batch, the entry's kernel, and the
    chamber → cavity incidence of each link."""

    rows: np.ndarray            # (k,) positions in the batch
    entry: FittedEntry
    links: np.ndarray           # (k,) trunk links
    segment: np.ndarray         # (k,) scene segments
    vertebra: np.ndarray        # (k,) distal vertebra of each link's repetition
    incidence: np.ndarray       # (k, cavities, chambers) 0/1: M of each link
    limit: float                # pressure with no equilibrium beyond it (inf: none known)
    met: bool                   # ``limit`` is the limit point met while sampling (else the fit's fold pressure)


def _limit_pressure(model: EnergyModel) -> tuple[float, bool]:
    """The pressure beyond which an entry's energy has no equilibrium: the limit point met while
    sampling or the fold of its pressure map, whichever is lower (inf when neither is known), and
    whether it is the limit point met while sampling."""
    fit = model.fit
    met, fold = fit.range.limit_pressure, fit.fold_pressure
    if met is not None and (fold is None or met <= fold):
        return float(met), True
    return (np.inf if fold is None else float(fold)), False


@dataclass(frozen=True)
class FittedEnergy:
    """Links of nonlinear catalogue entries, batched (see the module docstring)."""

    links: np.ndarray           # (n,) which links of the trunk
    rest: np.ndarray            # (n, 6) ξ₀
    fitted: ClassVar[bool] = True
    groups: tuple               # _Group per distinct entry
    n_chambers: int
    scale: np.ndarray | None = None   # (n,) multiplies each link's ψ (a stiffness scale); None: 1

    @classmethod
    def compile(cls, links: np.ndarray, compiled: CompiledLinks) -> "FittedEnergy":
        of = compiled.source_of_link[links]
        cavity = compiled.cavity[links]
        n_chambers = cavity.shape[1]
        by_key: dict[str, list[int]] = {}
        for s in np.unique(of).tolist():
            by_key.setdefault(compiled.sources[s].parameters.key, []).append(s)
        groups = []
        for sources in by_key.values():
            rows = np.flatnonzero(np.isin(of, sources))
            entry = compiled.sources[sources[0]].parameters
            m = entry.model.fit.n_cavities
            incidence = np.zeros((rows.size, m, n_chambers))
            for j in range(n_chambers):
                served = np.flatnonzero(cavity[rows, j] >= 0)
                incidence[served, cavity[rows[served], j], j] = 1.0
            groups.append(_Group(rows, entry, links[rows], of[rows], compiled.vertebra[links[rows]], incidence,
                                 *_limit_pressure(entry.model)))
        return cls(links, compiled.rest[of], tuple(groups), n_chambers)

    def scaled(self, scale: np.ndarray) -> "FittedEnergy":
        """The links with their energies multiplied by ``scale`` (n,) — a stiffness scale of their
        material (links with cavities refused, as for quadratic links)."""
        has_cavity = np.zeros(self.links.size, bool)
        for group in self.groups:
            has_cavity[group.rows] = group.incidence.shape[1] > 0
        refuse_scaled_cavities(scale, has_cavity)
        return dataclasses.replace(self, scale=None if np.all(scale == 1.0) else scale)

    def prepare(self, pressures: np.ndarray) -> tuple:
        """Every group's energy at its links' cavity pressures (one
        :class:`~vertebra.core.energy.FixedPressures` per group). Pressures at or beyond an
        entry's inflation limit point raise ConvergenceError."""
        if not pressures.size or not np.any(pressures):
            return tuple(group.entry.model.at(None) for group in self.groups)
        prepared = []
        for group in self.groups:
            if pressures.ndim == 2:        # a batch (B, chambers): rows sample by sample
                p = (group.incidence @ pressures[:, None, :, None])[..., 0].reshape(-1, group.incidence.shape[1])
                if np.all(p < group.limit):
                    prepared.append(group.entry.model.at(p))
                    continue
                p = group.incidence @ pressures[int(np.argmax(np.max(p.reshape(pressures.shape[0], -1), 1)))]
            else:
                p = group.incidence @ pressures
            if np.any(p >= group.limit):
                k = int(np.argmax(p.max(1)))
                c = int(np.argmax(p[k]))
                sampled = float(np.max(group.entry.model.fit.range.pressure_upper))
                where = (f"cavity {c} of segment {group.segment[k]} (entry {group.entry.name!r}, vertebrae "
                         f"{group.vertebra[k] - 1}–{group.vertebra[k]}) is pressurised to {p[k, c]:.6g} Pa")
                if group.met:
                    raise ConvergenceError(
                        f"{where}, at or beyond the inflation limit point met while its energy was sampled "
                        f"({group.limit:.6g} Pa; pressures sampled up to {sampled:.6g} Pa): the chamber has no "
                        "equilibrium there (it balloons), and the fit is not extrapolated through the limit point")
                raise ConvergenceError(
                    f"{where}, at or beyond the fold pressure of its fitted energy's pressure map ({group.limit:.6g} "
                    f"Pa), where the fit's pressure map ends; no limit point was met while sampling, which reached "
                    f"{sampled:.6g} Pa: the fit cannot be evaluated there (sampling the entry to higher pressures "
                    "tells whether the chamber has a limit point)")
            prepared.append(group.entry.model.at(p))
        return tuple(prepared)

    def _evaluate(self, group: _Group, xi: np.ndarray, fixed: FixedPressures, **what) -> EnergyValues:
        """The group's values at the strains ``xi`` (n, 6), or (B, n, 6) for a batch (rows sample
        by sample)."""
        rows = group.rows
        if xi.ndim > 2:
            return fixed.evaluate((xi[..., rows, :] - self.rest[rows]).reshape(-1, 6), **what)
        return fixed.evaluate(xi[rows] - self.rest[rows], **what)

    def response(self, xi: np.ndarray, prepared: tuple) -> tuple[float, np.ndarray, tuple]:
        """ψ, ``w = ∂ψ/∂s`` and (kept for the tangent) ``∂²ψ/∂s²``: the strain derivatives only.
        For a batch ``xi`` (B, n, 6) (prepared by :meth:`prepare` of (B, chambers) pressures), Σ ψ
        per sample (B,); the kept values hold the rows of every sample, sample by sample."""
        scale = self.scale
        batch = xi.shape[:-2]
        if len(self.groups) == 1:
            if batch:
                values = prepared[0].evaluate((xi - self.rest).reshape(-1, 6), derivatives=0, check_range=False)
                energy, gradient = values.energy.reshape(xi.shape[:-1]), values.gradient.reshape(xi.shape)
                if scale is not None:
                    energy, gradient = scale * energy, scale[:, None] * gradient
                return np.add.reduce(energy, -1), gradient, (values,)
            values = prepared[0].evaluate(xi - self.rest, derivatives=0, check_range=False)
            if scale is None:
                return float(values.energy.sum()), values.gradient, (values,)
            return float(scale @ values.energy), scale[:, None] * values.gradient, (values,)
        total, w, kept = (np.zeros(batch) if batch else 0.0), np.empty_like(xi), []
        for group, fixed in zip(self.groups, prepared):
            rows = group.rows
            s = xi[..., rows, :] - self.rest[rows]
            values = fixed.evaluate(s.reshape(-1, 6) if batch else s, derivatives=0, check_range=False)
            energy, gradient = values.energy.reshape(s.shape[:-1]), values.gradient.reshape(s.shape)
            if batch:
                if scale is not None:
                    energy, gradient = scale[rows] * energy, scale[rows, None] * gradient
                total = total + np.add.reduce(energy, -1)
            elif scale is None:
                total += float(energy.sum())
            else:
                total += float(scale[rows] @ energy)
                gradient = scale[rows, None] * gradient
            w[..., rows, :] = gradient
            kept.append(values)
        return total, w, tuple(kept)

    def material_tangent(self, xi: np.ndarray, prepared: tuple, kept: tuple) -> np.ndarray:
        """``∂²ψ/∂s²`` (n, 6, 6), or (B·n, 6, 6) sample by sample for a batch."""
        batch = xi.shape[:-2]
        if len(self.groups) == 1:
            hessian = kept[0].hessian
        else:
            hessian = np.empty(xi.shape[:-1] + (6, 6))
            for group, values in zip(self.groups, kept):
                hessian[..., group.rows, :, :] = values.hessian.reshape(batch + (-1, 6, 6))
            hessian = hessian.reshape(-1, 6, 6)
        if self.scale is None:
            return hessian
        return (np.tile(self.scale, batch) if batch else self.scale)[:, None, None] * hessian

    def chamber_forces(self, xi: np.ndarray, prepared: tuple, kept: tuple) -> np.ndarray:
        """``−∂²ψ/∂s∂p · M`` per link (n, chambers, 6); (B, n, chambers, 6) for a batch ``xi`` (B, n, 6)."""
        batch = xi.shape[:-2]
        out = np.zeros(batch + (xi.shape[-2], self.n_chambers, 6))
        if self.n_chambers:
            for group, fixed in zip(self.groups, prepared):
                values = self._evaluate(group, xi, fixed, derivatives=1)
                mixed = values.mixed_hessian.reshape(batch + (-1,) + values.mixed_hessian.shape[1:])
                out[..., group.rows, :, :] = -np.einsum("...kim,kmj->...kji", mixed, group.incidence)
        return out

    def volume_growth(self, xi: np.ndarray, prepared: tuple, pressures: np.ndarray) -> np.ndarray:
        """``−(∂ψ/∂p) · M`` summed over the links (chambers,)."""
        total = np.zeros(self.n_chambers)
        if self.n_chambers:
            for group, fixed in zip(self.groups, prepared):
                values = self._evaluate(group, xi, fixed, derivatives=1)
                total += np.einsum("km,kmj->j", values.volume_growth, group.incidence)
        return total

    def out_of_range(self, xi: np.ndarray, prepared: tuple) -> tuple[RangeExcess, ...]:
        found = []
        for group, fixed in zip(self.groups, prepared):
            values = self._evaluate(group, xi, fixed, derivatives=1)
            if not np.any(values.range_excess > 0.0):
                continue
            fitted = group.entry.model.fit.range
            s = xi[group.rows] - self.rest[group.rows]
            p = np.zeros((s.shape[0], fitted.n_cavities)) if fixed.p is None else fixed.p
            quantities = fitted.values(s, values.gradient, p)
            excess = fitted.excesses(s, values.gradient, p)
            lower, upper = fitted.bounds
            names = fitted.quantities
            for k, q in zip(*np.nonzero(excess > 0.0)):
                found.append(RangeExcess(
                    link=int(group.links[k]), segment=int(group.segment[k]),
                    vertebrae=(int(group.vertebra[k]) - 1, int(group.vertebra[k])), source=group.entry.name,
                    quantity=names[q], value=float(quantities[k, q]), lower=float(lower[q]),
                    upper=float(upper[q]), excess=float(excess[k, q])))
        return tuple(found)


def fitted_link(segment, entry) -> LinkSource:
    return dataclasses.replace(entry_link(segment, entry),
                               parameters=FittedEntry(entry.name, entry.key, EnergyModel.of_entry(entry)))


@dataclass(frozen=True)
class FittedKind:
    """Catalogue entries that carry a fitted energy (``entry.energy``); entries without one stay
    quadratic (the ``linear-entry`` kind)."""

    name: ClassVar[str] = "nonlinear-entry"
    priority: ClassVar[int] = 1
    energy: ClassVar[type] = FittedEnergy

    def claims(self, segment, entry) -> bool:
        return segment.type == "entry" and getattr(entry, "energy", None) is not None

    def source(self, segment, entry) -> LinkSource:
        return fitted_link(segment, entry)


register(FittedKind())
