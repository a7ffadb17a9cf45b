"""Catalogue entries with a linear condensation (``type = "entry"`` segments) as quadratic links.

The entry's symmetric compliance ``[[C, G], [Gᵀ, V]]``, rest pose, mass properties and cavity
rest volumes make one link per repetition.
"""

from __future__ import annotations

import numpy as np

from vertebra.solver.kinds import LinkSource, register
from vertebra.solver.kinds.quadratic import Compliance, QuadraticKind


def entry_link(segment, entry) -> LinkSource:
    return LinkSource(np.asarray(entry.rest_quaternion, float), np.asarray(entry.rest_translation, float),
                      float(entry.mass), np.asarray(entry.center_of_mass, float),
                      np.asarray(entry.cavity_volumes, float), Compliance(entry.C, entry.G, entry.V))


register(QuadraticKind("linear-entry", "entry", entry_link))
