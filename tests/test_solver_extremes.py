"""Numerical stability at the extremes (DESIGN §7): every case converges or raises
ConvergenceError — never NaN, never a silent wrong answer."""

import math

import numpy as np
import pytest

from vertebra import solver
from vertebra.solver.analytic import elastica_tip
from vertebra.core.errors import ConvergenceError


def cantilever(elements, length, youngs, radius, force=(0, 0, 0), moment=(0, 0, 0), nu=0.3):
    return solver.build_model(solver.parse_scene({
        "segment": [{"type": "beam", "elements": elements, "length": length, "youngs_modulus": youngs,
                     "poisson_ratio": nu, "section": {"shape": "circle", "radius": radius}}],
        "load": [{"vertebra": -1, "force": list(force), "moment": list(moment)}]}))


@pytest.mark.parametrize("youngs", [1e3, 1e6, 1e9, 2e11])
@pytest.mark.parametrize("length", [1e-3, 1.0])
def test_materials_and_sizes_across_eleven_decades(youngs, length):
    # same shape problem (PL²/EI = 2, slenderness 100) for E from 1 kPa to 200 GPa and L from 1 mm
    # to 1 m: same dimensionless answer to 1e-6 of the length
    radius = length / 100
    EI = youngs * math.pi * radius ** 4 / 4
    model = cantilever(20, length, youngs, radius, force=(2.0 * EI / length ** 2, 0, 0))
    tip = model.solve().state.positions[-1] / length
    reference = elastica_tip(2.0)
    # slender (L/r = 100) extensible beam vs inextensible elastica: ~1e-4
    assert abs(tip[0] - reference[0]) < 5e-4 and abs(tip[2] - reference[1]) < 5e-4


def test_nearly_incompressible_and_zero_poisson_sections():
    for nu in (0.0, 0.4999):
        model = cantilever(10, 0.1, 1e6, 1e-3, force=(1e-4, 0, 0), nu=nu)
        assert model.solve().converged


@pytest.mark.parametrize("links", [1, 10_000])
def test_one_to_ten_thousand_frames(links):
    EI = 200e9 * math.pi * 1e-12 / 4
    model = cantilever(links, 0.5, 200e9, 1e-3, force=(1.0 * EI / 0.25, 0, 0))
    result = model.solve()
    assert result.converged and np.all(np.isfinite(result.state.positions))
    if links > 1:
        reference = elastica_tip(1.0, 0.5)
        assert np.hypot(result.state.positions[-1, 0] - reference[0], result.state.positions[-1, 2] - reference[1]) < 1e-4


def test_coil_beyond_two_turns():
    EI = 200e9 * math.pi * 1e-12 / 4
    angle = 2.2 * 2 * math.pi
    model = cantilever(80, 0.5, 200e9, 1e-3, moment=(0, angle * EI / 0.5, 0))
    result = model.solve()
    radius = 0.5 / angle
    expected = [radius * (1 - math.cos(angle)), radius * math.sin(angle)]
    tip = result.state.positions[-1]
    assert result.converged and np.hypot(tip[0] - expected[0], tip[2] - expected[1]) < 1e-6


def test_absurd_load_converges_or_raises_never_nan():
    # 1 MN on a 1 mm steel wire: PL²/EI ≈ 1.6e6 and strains of ~500 under the linear law; the
    # model's answer is a wire stretched along the force. Either that, or a ConvergenceError with
    # a finite partial state — never NaN.
    model = cantilever(10, 0.5, 200e9, 1e-3, force=(1e6, 0, 0))
    try:
        result = model.solve(max_iterations=30)
    except ConvergenceError as error:
        result = error.result
        assert not result.converged
    else:
        tip = result.state.positions[-1]
        assert result.converged and abs(tip[2]) < 1e-2 * tip[0]
    assert np.all(np.isfinite(result.state.positions)) and np.all(np.isfinite(result.state.quaternions))


def test_tiny_loads_resolve_at_the_rounding_floor():
    model = cantilever(10, 0.5, 200e9, 1e-3, force=(1e-12, 0, 0))
    result = model.solve()
    EI = 200e9 * math.pi * 1e-12 / 4
    assert result.converged
    assert abs(result.state.positions[-1, 0] - 1e-12 * 0.5 ** 3 / (3 * EI)) < 1e-3 * 1e-12 * 0.5 ** 3 / (3 * EI)
