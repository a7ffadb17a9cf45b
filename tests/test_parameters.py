"""Loads and parameters changed between solves without compiling the scene again: each change
gives exactly the equilibrium of a scene compiled with it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vertebra import solver
from vertebra.core.errors import OptionError

ROD = {"type": "beam", "count": 6, "length": 0.02, "elements": 2, "youngs_modulus": 54e9, "poisson_ratio": 0.3,
       "section": {"shape": "circle", "radius": 0.0007}, "density": 6450.0, "vertebra": {"mass": 0.002}}


def scene(**changes):
    data = _scene_data()
    data.update(changes)
    return solver.build_model(solver.parse_scene(data))


def same(a, b, model):
    return np.abs(a.state.positions - b.state.positions).max() <= 1e-10 * model.length_scale


def test_each_runtime_change_gives_the_equilibrium_of_the_scene_compiled_with_it():
    model = scene()
    first = model.solve()
    base = model.parameters
    cases = [
        ({"gravity": [0.0, 0.0, -9.81]}, {"gravity": {"vector": [0.0, 0.0, -9.81]}}),
        ({"dead": {4: [0.0, 0.03, 0.0, 0.0, 0.0, 0.001], -1: [0.01, 0.0, 0.0, 0.0, 0.0, 0.0]}},
         {"load": [{"vertebra": 4, "force": [0.0, 0.03, 0.0], "moment": [0.0, 0.0, 0.001]},
                   {"vertebra": -1, "force": [0.01, 0.0, 0.0]}]}),
        ({"follower": {-1: [0.0, 0.02, 0.0, 0.0, 0.0, 0.002], 7: [0.01, 0.0, 0.0, 0.001, 0.0, 0.0]}},
         {"load": [{"vertebra": 4, "force": [0.02, 0.0, 0.0]},
                   {"vertebra": -1, "force": [0.0, 0.02, 0.0], "moment": [0.0, 0.0, 0.002], "follower": True},
                   {"vertebra": 7, "force": [0.01, 0.0, 0.0], "moment": [0.001, 0.0, 0.0], "follower": True}]}),
        ({"hole_angle": {"a": math.radians(25.0)}, "hole_radius": {"c": 0.006}}, None),
        ({"cable_stiffness": {"a": 1500.0}, "pretension": {"b": 0.9}}, None),
        ({"stiffness_scale": {1: 1.3}}, None),
    ]
    for changes, scene_changes in cases:
        model.set_parameters(base, **changes)
        result = model.solve(initial=first.state)
        assert result.converged
        if scene_changes is None:        # the same change written into the scene
            data = _scene_data()
            for name, value in changes.items():
                for key, v in value.items():
                    if name == "stiffness_scale":       # E (and G = E/2(1 + ν)) scaled: every compliance / s
                        data["segment"][key]["youngs_modulus"] *= v
                    else:
                        cable = next(c for c in data["cable"] if c["name"] == key)
                        field = {"hole_angle": "angle_deg", "hole_radius": "radius", "cable_stiffness": "stiffness",
                                 "pretension": "pretension"}[name]
                        cable[field] = math.degrees(v) if name == "hole_angle" else v
            reference = solver.build_model(solver.parse_scene(data)).solve()
        else:
            reference = scene(**scene_changes).solve()
        assert same(result, reference, model), changes
    model.set_parameters(base)
    assert same(model.solve(), first, model)


def _scene_data():
    return {"solver": {"tolerance": 1e-13},
            "segment": [dict(ROD), dict(ROD, count=4, youngs_modulus=70e9)],
            "cable": [{"name": "a", "radius": 0.008, "angle_deg": 10.0, "to": 10, "stroke": 0.001,
                       "stiffness": 3000.0, "pretension": 0.4},
                      {"name": "b", "radius": 0.008, "angle_deg": 190.0, "to": 6, "stroke": 0.0,
                       "axial_stiffness": 2000.0, "pretension": 0.2},
                      {"name": "c", "radius": 0.008, "angle_deg": 100.0, "to": 10, "tension": 0.5}],
            "gravity": {"vector": [0.0, -9.81, 0.0]},
            "load": [{"vertebra": 4, "force": [0.02, 0.0, 0.0]}],
            "effector": [{"name": "tip", "vertebra": -1}]}


def test_parameters_are_checked():
    model = scene()
    for changes, message in (({"gravity": [1.0, 2.0]}, "3 values"),
                             ({"cable_stiffness": {"c": 10.0}}, "stroke-driven tendons only"),
                             ({"stiffness_scale": {5: 1.0}}, "out of range"), ({"hole_angle": {"z": 1.0}}, "unknown cable"),
                             ({"mass": 1.0}, "unknown parameter"), ({"stiffness_scale": {0: 0.0}}, "positive"),
                             ({"gravity": [0.0, math.nan, 0.0]}, "non-finite")):
        with pytest.raises(OptionError, match=message):
            model.with_parameters(**changes)
