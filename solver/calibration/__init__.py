"""Calibration of a scene against measured static samples (docs/calibration.md).

``calibrate(scene, mapping, train, holdout, fit)`` fits named scene parameters (segment
stiffness, hole geometry, tendon stiffness and pretension, the measurement frame, marker
offsets) by bounded nonlinear least squares and reports the fitted values with their standard
errors, their correlations and the tip errors on training and held-out samples.
"""

from vertebra.solver.calibration.data import (Mapping, MappingError, Samples, load_mapping, load_samples,
                                              parse_mapping)
from vertebra.solver.calibration.fit import Calibration, LOSSES, METHODS, calibrate, error_metrics
from vertebra.solver.calibration.fit_parameters import KINDS, ParameterSet, Values, parse_parameters

__all__ = ["Calibration", "KINDS", "LOSSES", "METHODS", "Mapping", "MappingError", "ParameterSet", "Samples",
           "Values", "calibrate", "error_metrics", "load_mapping", "load_samples", "parse_mapping",
           "parse_parameters"]
