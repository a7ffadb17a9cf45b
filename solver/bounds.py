"""The scene's actuator bounds, checked on a forward solve.

A forward solve does what it is asked — a tension beyond ``max_tension`` or a stroke beyond
``min_stroke`` is a question a user may want answered — and says what it broke: every
:class:`BoundViolation` of its result (``StaticResult.bound_violations``), reported in the
JSON of ``vertebra simulate`` and ``vertebra invert`` and as warnings on stderr. What is checked:

* a tension-driven cable: its tension (``min_tension``/``max_tension``) and its stroke
  ``L − L0`` (``min_stroke``/``max_stroke``);
* a stroke-driven tendon: its servo stroke, the command (``min_stroke``/``max_stroke``), and the
  tension that stroke produces at the state (``max_tension``, and ``min_tension`` when set above
  zero);
* a chamber: its pressure (``min_pressure``/``max_pressure``) and volume growth
  (``min_volume_growth``/``max_volume_growth``).

One thing is refused instead: a cable cannot push. A negative tension on a tension-driven cable
is an :class:`~vertebra.core.errors.OptionError` (a :class:`~vertebra.core.errors.SceneError`
when the scene's own ``tension`` is negative) unless the scene allows it with a negative
``min_tension`` (a push–pull actuator, e.g. a rod). The range a fitted link energy was sampled on
is reported apart (``out_of_range``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vertebra.core.errors import OptionError, SceneError

__all__ = ["BoundViolation", "bound_violations", "check_pushing"]

RELATIVE = 1e-9     # a value this close to its bound (relative to the bound or the quantity's scale) is on it

UNITS = {"tension": "N", "stroke": "m", "servo stroke": "m", "pressure": "Pa", "volume growth": "m^3"}


@dataclass(frozen=True)
class BoundViolation:
    """A quantity of an actuator beyond one of its scene bounds: ``value`` lies ``excess`` (in
    the quantity's unit, > 0) beyond ``limit``, the scene field ``bound`` of actuator ``actuator``."""

    actuator: str
    quantity: str       # "tension", "stroke", "servo stroke", "pressure", "volume growth"
    bound: str          # the scene field: "max_tension", "min_stroke", …
    limit: float
    value: float
    excess: float

    @property
    def unit(self) -> str:
        return UNITS[self.quantity]

    def to_dict(self) -> dict:
        return {"actuator": self.actuator, "quantity": self.quantity, "bound": self.bound, "limit": self.limit,
                "value": self.value, "excess": self.excess, "unit": self.unit}

    def __str__(self) -> str:
        side = "above" if self.bound.startswith("max") else "below"
        return (f"{self.actuator}: {self.quantity} {self.value:.6g} {self.unit} is {self.excess:.6g} {self.unit} "
                f"{side} its {self.bound} {self.limit:.6g} {self.unit}")


def _check(found: list, names, quantity: str, field: str, values, lower, upper, scale) -> None:
    """Append the entries of ``values`` outside ``[lower, upper]`` (beyond :data:`RELATIVE` of
    the bound or of ``scale``)."""
    values = np.asarray(values, dtype=float)
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    slack = RELATIVE * np.maximum(np.abs(np.where(np.isfinite(lower), lower, 0.0)),
                                  np.abs(np.where(np.isfinite(upper), upper, 0.0))) + RELATIVE * scale
    below, above = values < lower - slack, values > upper + slack
    for k in np.flatnonzero(below | above).tolist():
        limit = float(lower[k] if below[k] else upper[k])
        found.append(BoundViolation(names[k], quantity, ("min_" if below[k] else "max_") + field, limit,
                                    float(values[k]), abs(float(values[k]) - limit)))


def bound_violations(model, state, actuation) -> tuple:
    """Every :class:`BoundViolation` of ``actuation`` and of the actuator quantities at ``state``
    (module docstring), cables then chambers; empty when everything is within its bounds."""
    actuators = model.trunk.actuators
    names = actuators.names
    n_cables = actuators.n_cables
    actuation = np.asarray(actuation, dtype=float)
    lower, upper = actuators.bounds
    dlo, dhi = actuators.displacement_bounds
    driven = actuators.stroke_driven
    cables = model.scene.cables
    outside = (actuation < lower) | (actuation > upper)
    on_state = actuators.state_bounded
    tendons = [k for k in actuators.tendons.tolist()
               if math.isfinite(cables[k].max_tension) or cables[k].min_tension > 0.0] if actuators.tendons.size else []
    if not (on_state or tendons or outside.any()):
        return ()
    found: list = []
    tension_max = max((c.max_tension for c in cables if math.isfinite(c.max_tension)), default=0.0)
    # the commands: tensions (tension-driven), servo strokes (stroke-driven), pressures
    quantities = [("servo stroke", "stroke") if s else ("tension", "tension") for s in driven.tolist()]
    quantities += [("pressure", "pressure")] * actuators.n_chambers
    scales = np.array([model.length_scale if s else tension_max for s in driven.tolist()]
                      + [float(np.max(np.abs(upper[n_cables:]), initial=0.0, where=np.isfinite(upper[n_cables:])))]
                      * actuators.n_chambers)
    for k in np.flatnonzero(outside).tolist():
        quantity, field = quantities[k]
        _check(found, names[k:k + 1], quantity, field, actuation[k:k + 1], lower[k:k + 1], upper[k:k + 1],
               scales[k])
    # what the state makes of them: strokes and volume growths, tendon tensions
    if on_state:
        displacements = model.actuator_displacements(state, actuation)
        rows = np.flatnonzero(np.isfinite(dlo) | np.isfinite(dhi))
        for k in rows.tolist():
            if k < n_cables:
                _check(found, names[k:k + 1], "stroke", "stroke", displacements[k:k + 1], dlo[k:k + 1],
                       dhi[k:k + 1], model.length_scale)
            else:
                scale = float(model.chamber_rest_volumes[k - n_cables])
                _check(found, names[k:k + 1], "volume growth", "volume_growth", displacements[k:k + 1],
                       dlo[k:k + 1], dhi[k:k + 1], scale)
    if tendons:
        tensions = model.cable_tensions(state, actuation)
        for k in tendons:
            _check(found, names[k:k + 1], "tension", "tension", tensions[k:k + 1], [cables[k].min_tension],
                   [cables[k].max_tension], tension_max)
    order = {name: i for i, name in enumerate(names)}
    return tuple(sorted(found, key=lambda v: order[v.actuator]))


def check_pushing(model, actuation, *, from_scene: bool = False) -> None:
    """Refuse a negative tension on a tension-driven cable whose scene does not allow one (its
    ``min_tension`` ≥ 0): :class:`OptionError` naming the cable, or :class:`SceneError` naming the
    scene's field when ``from_scene`` (the values are the scene's own)."""
    actuators = model.trunk.actuators
    n = actuators.n_cables
    if not n:
        return
    tensions = np.asarray(actuation, dtype=float)[:n]
    if not np.minimum.reduce(tensions) < 0.0:
        return
    pushing = (tensions < 0.0) & ~actuators.stroke_driven & (actuators.bounds[0][:n] >= 0.0)
    if not pushing.any():
        return
    k = int(np.flatnonzero(pushing)[0])
    name = actuators.names[k]
    message = (f"cable {name!r} would push with a tension of {tensions[k]:g} N: a cable only pulls (give it "
               f"min_tension < 0 in the scene for a push–pull actuator)")
    if from_scene:
        raise SceneError(message, file=model.scene.source, field=f"cable[{k}].tension")
    raise OptionError(message, field="actuation")
