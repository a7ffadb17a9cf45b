"""Beam links: analytic Timoshenko sections (``type = "beam"`` segments) as quadratic links.

A repetition of length ``l`` with ``elements`` links makes links of length ``l / elements``,
each with the closed-form cantilever compliance of its length (:mod:`vertebra.solver.timoshenko`),
its mass ``ρ A l`` at mid-length, and no cavities.
"""

from __future__ import annotations

import numpy as np

from vertebra.solver.timoshenko import timoshenko_compliance
from vertebra.solver.kinds import LinkSource, register
from vertebra.solver.kinds.quadratic import Compliance, QuadraticKind


def beam_link(segment, entry) -> LinkSource:
    length = segment.length / segment.elements
    try:
        C = timoshenko_compliance(length, segment.youngs_modulus, segment.shear_modulus, segment.section)
    except (OverflowError, ZeroDivisionError):
        C = np.full((6, 6), np.inf)          # refused by the energy's compile, naming the segment
    return LinkSource(np.array([1.0, 0.0, 0.0, 0.0]), np.array([0.0, 0.0, length]),
                      segment.density * segment.section.area * length, np.array([0.0, 0.0, 0.5 * length]),
                      np.zeros(0), Compliance(C, np.zeros((6, 0)), np.zeros((0, 0))))


register(QuadraticKind("beam", "beam", beam_link))
