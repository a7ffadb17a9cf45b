"""What a model remembers between calls. Every entry is keyed so that it cannot go stale.

* The link kinematics of the rest state (a model constant) and of the last composed state
  evaluated, keyed by its strain record, whose arrays are read-only: a Newton step, or a step
  of the inverse from the state just linearised, reuses them. States given by their poses only
  are not remembered.
* The links' tangent at the unstressed rest state and its diagonal, the stiffness scale of
  every DoF (model constants).
* What the potential at the last composed state judged computed on the way (link responses,
  cable spans, mass moments), keyed by its strain record and load case: the evaluation of that
  state under that load (the next control tick's) reuses them.
* The load cases of the last two (actuation, load factor) and the reference force of the last
  actuation: repeated solves and linearisations at one actuation compute them once, a control
  tick's two actuations (linearised at one, stepped to the other) alternate without rebuilding,
  and a new actuation at the same load factor (a control loop's) keeps the weight and dead loads.
  What the link energies prepared of given chamber pressures comes from those load cases, or
  from the last pressures asked for (volume growths reported at other pressures).
"""

from __future__ import annotations

import numpy as np

from vertebra.solver.energy import LoadCase, evaluate, tangent
from vertebra.solver.links import Links


class Memo:
    """The remembered values of one compiled trunk (see the module docstring)."""

    def __init__(self, trunk):
        self._trunk = trunk
        self._rest_record = trunk.rest_state.strains
        self._rest_links = None
        self._last = (None, None)
        self._unstressed = None
        self._stiffness = None
        self._axes = None
        self._loads = [(None, None, None), (None, None, None)]   # the last two, most recent first
        self._reference = (None, None)
        self._link_loads = (None, None)
        self._potential = (None, None, None)

    def links(self, state, record) -> Links:
        """Link kinematics of ``state`` (``record``: its carried strains or None)."""
        if record is None:
            q, x = state.quaternions, state.positions
            return Links.of(q[:-1], x[:-1], q[1:], x[1:])
        if record is self._rest_record:
            if self._rest_links is None:
                self._rest_links = record.kinematics()
            return self._rest_links
        last, links = self._last
        if record is not last:
            links = record.kinematics()
            self._last = (record, links)
        return links

    def keep_potential_parts(self, record, load, parts) -> None:
        """Keep what the potential at the state of strain ``record`` under ``load`` computed."""
        self._potential = (record, load, parts)

    def potential_parts(self, record, load):
        """What the potential computed at the state of ``record`` under ``load``, else None."""
        kept_record, kept_load, parts = self._potential
        if record is None or record is not kept_record or load is not kept_load:
            return None
        return parts

    def unstressed_tangent(self, compute) -> np.ndarray:
        """The links' tangent at the unstressed rest state (``compute()`` the first time)."""
        if self._unstressed is None:
            self._unstressed = compute()
        return self._unstressed

    def stiffness_scale(self) -> np.ndarray:
        """Diagonal (n_dof,) of the tangent at the unstressed rest state: the stiffness of every
        DoF in its own units (positive: every free frame has a link)."""
        if self._stiffness is None:
            trunk = self._trunk
            unloaded = LoadCase.of(trunk, np.zeros(trunk.actuators.default.size), 0.0)
            ev = evaluate(trunk, trunk.rest_state, unloaded, self)
            self._stiffness = tangent(trunk, ev, self).diagonal().copy()
            self._stiffness.flags.writeable = False
        return self._stiffness

    def link_axes(self) -> tuple[np.ndarray, float]:
        """``(ρ₀/|ρ₀|², shortest |ρ₀|)`` of the links' rest translation strains ``ρ₀``: a link's
        axial stretch is ``ρ · axis``."""
        if self._axes is None:
            rest = self._trunk.links.rest[:, :3]
            squared = np.einsum("ij,ij->i", rest, rest)
            axis = rest / squared[:, None]
            axis.flags.writeable = False
            self._axes = (axis, float(np.sqrt(squared.min())))
        return self._axes

    def load_case(self, actuation: np.ndarray, scale: float) -> LoadCase:
        """The load case of ``actuation`` at load factor ``scale`` (the last two are kept: a
        control tick judges its step under the new actuation while the next one linearises)."""
        key = actuation.tobytes()
        loads = self._loads
        for k, (last_key, last_scale, load) in enumerate(loads):
            if last_key == key and last_scale == scale:
                if k:
                    loads.reverse()
                return load
        load = LoadCase.of(self._trunk, actuation, scale, loads[0][2])
        loads[1], loads[0] = loads[0], (key, scale, load)
        return load

    def link_loads(self, pressures: np.ndarray) -> tuple:
        """What the link energies prepared of the chamber ``pressures`` (the remembered load
        cases' when one has these pressures)."""
        for _, _, load in self._loads:
            if load is not None and np.array_equal(load.pressures, pressures):
                return load.link_loads
        key = pressures.tobytes()
        if self._link_loads[0] != key:
            self._link_loads = (key, tuple(e.prepare(pressures) for e in self._trunk.links.energies))
        return self._link_loads[1]

    def reference_force(self, actuation: np.ndarray, compute) -> float:
        """The reference force of ``actuation`` (``compute()`` when it is not the last one)."""
        key = actuation.tobytes()
        if self._reference[0] != key:
            self._reference = (key, compute())
        return self._reference[1]
