"""Bounded nonlinear least squares of a scene's parameters against measured markers.

:func:`calibrate` minimises ``Σ ρ(|predicted − measured|²)`` over the chosen parameters with
scipy's ``least_squares`` (``trf`` with bounds, or ``lm`` without), on the analytic derivatives
of the predictor (:mod:`~vertebra.solver.calibration.backend`); an optional robust loss
(``soft_l1``, ``huber``, ``cauchy``, ``arctan``) and several starts (the first at the initial
values, the others drawn inside the bounds) for multimodal problems. At the optimum it reports
each value with its standard error from ``σ² (JᵀJ)⁻¹`` (``σ²`` the residual variance), the
correlation matrix, and which parameters the data cannot identify.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import OptimizeResult, least_squares, lsq_linear

from vertebra.core.errors import OptionError
from vertebra.solver.calibration.backend import default_workers
from vertebra.solver.calibration.sequence import SequencePredictor
from vertebra.solver.calibration.fit_parameters import ParameterSet, Values, parse_parameters

__all__ = ["Calibration", "LOSSES", "METHODS", "calibrate", "error_metrics"]

LOSSES = ("linear", "soft_l1", "huber", "cauchy", "arctan")
METHODS = ("trf", "lm")
# relative singular value below which a direction of the (column-normalised) Jacobian is
# taken as unseen by the data: the derivatives are exact at equilibria converged to the solver's
# tolerance (~1e-8 relative), so directions this much weaker than the strongest are rounding
RANK_TOLERANCE = 1e-6
# a parameter whose weight in the unseen directions exceeds this is reported unidentifiable
NULL_WEIGHT = 0.1
# a parameter whose standard error exceeds this share of its bound interval is unidentifiable
SE_SHARE = 0.5
# the fit stops when the Gauss–Newton step is below this many standard errors (module docstring)
STEP_TOLERANCE = 0.1


@dataclass
class Calibration:
    """Outcome of a calibration: the fitted parameters with their statistics, the elements they
    set, the predictions and the error metrics, with diagnostics."""

    parameters: ParameterSet
    x: np.ndarray                   # fitted values of the parameters
    standard_errors: np.ndarray     # nan where not identifiable
    correlation: np.ndarray
    identifiable: np.ndarray        # bool
    at_bound: np.ndarray            # bool
    values: Values                  # every element, fitted ones set
    length: float                   # trunk length (m): the reference of the % errors
    train: dict                     # error metrics on the training samples
    holdout: dict | None
    train_prediction: np.ndarray    # (n, n_markers, 3) m
    holdout_prediction: np.ndarray | None
    train_samples: object
    holdout_samples: object
    sigma: float                    # residual standard deviation per coordinate, m
    optimiser: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)


def error_metrics(predicted, measured, patterns, length) -> dict:
    """Tip errors (m and % of ``length``) as measured and after removing the constant offset
    (the mean error vector), overall and per pattern."""
    residual = predicted - measured                        # (n, n_markers, 3)

    def summary(r):
        e = np.linalg.norm(r, axis=-1).reshape(-1)
        stats = {"n": int(e.size), "rmse_m": float(np.sqrt(np.mean(e ** 2))), "mean_m": float(e.mean()),
                 "median_m": float(np.median(e)), "p95_m": float(np.percentile(e, 95)), "max_m": float(e.max())}
        for key in ("rmse", "mean", "median", "p95", "max"):
            stats[f"{key}_pct_length"] = 100.0 * stats[f"{key}_m"] / length
        return stats

    offset = residual.mean(axis=0)
    out = summary(residual)
    out["offset_m"] = offset.tolist()
    out["offset_removed"] = summary(residual - offset)
    names = list(dict.fromkeys(patterns))
    per = {}
    for name in names:
        mask = np.array([p == name for p in patterns])
        s = summary(residual[mask])
        per[name] = {"n": s["n"], "rmse_m": s["rmse_m"], "rmse_pct_length": s["rmse_pct_length"],
                     "max_m": s["max_m"],
                     "offset_removed_rmse_m": float(np.sqrt(np.mean(np.sum((residual[mask] - offset) ** 2, -1))))}
    out["patterns"] = per
    return out


def _statistics(J, residual, ps: ParameterSet, x):
    """Standard errors, correlation and identifiability from the Jacobian in value units."""
    m, p = J.shape
    dof = max(m - p, 1)
    sigma2 = float(residual @ residual) / dof
    norms = np.linalg.norm(J, axis=0)
    seen = norms > 0.0
    Jn = np.where(seen, J / np.where(seen, norms, 1.0), 0.0)
    _, s, Vt = np.linalg.svd(Jn, full_matrices=False)
    keep = s > RANK_TOLERANCE * (s[0] if s.size and s[0] > 0 else 1.0)
    V = Vt.T
    null_weight = np.sqrt(np.sum(V[:, ~keep] ** 2, axis=1)) if (~keep).any() else np.zeros(p)
    cov_n = (V[:, keep] / s[keep] ** 2) @ V[:, keep].T
    scale = np.where(seen, norms, np.inf)
    cov = sigma2 * cov_n / np.outer(scale, scale)
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    identifiable = seen & (null_weight < NULL_WEIGHT) & (se < SE_SHARE * (ps.upper - ps.lower))
    se = np.where(seen & (null_weight < NULL_WEIGHT), se, np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(np.sqrt(np.diag(cov)), np.sqrt(np.diag(cov)))
    corr[~np.isfinite(corr)] = np.nan
    np.fill_diagonal(corr, 1.0)
    return se, corr, identifiable, float(np.sqrt(sigma2)), {"rank": int(keep.sum()),
                                                            "singular_values": s.tolist()}


def calibrate(scene, mapping, train, holdout=None, fit=None, *, loss: str = "linear",
              loss_scale: float | None = None, method: str = "trf", starts: int = 1, seed: int = 0,
              max_evaluations: int = 60, ftol: float = 1e-6, xtol: float = 1e-6,
              step_tolerance: float = STEP_TOLERANCE, predictor=None, workers: int | None = None,
              progress=None) -> Calibration:
    """Fit ``fit`` (parameter specifications; the mapping's ``[fit]`` list when None) of
    ``scene`` to the ``train`` samples and measure the result on ``holdout``.

    ``loss``: one of :data:`LOSSES`; ``loss_scale`` (m): the residual at which a robust loss
    starts to discount (default: 1 % of the trunk length). ``method``: ``trf`` (bounded) or
    ``lm`` (unbounded; the bounds are then only checked). ``workers``: processes solving the
    samples (default: one per core, at most one per
    :data:`~vertebra.solver.calibration.backend.SAMPLES_PER_WORKER` training samples).
    ``step_tolerance``: stop when the Gauss–Newton step is below this many standard errors
    (module docstring; 0: scipy's ``ftol``/``xtol`` alone; linear loss only).
    ``progress``: a callable taking a one-line message."""
    t_start = time.perf_counter()
    if loss not in LOSSES:
        raise OptionError(f"unknown loss {loss!r}; one of {', '.join(LOSSES)}", field="--loss")
    if method not in METHODS:
        raise OptionError(f"unknown method {method!r}; one of {', '.join(METHODS)}", field="--method")
    if method == "lm" and loss != "linear":
        raise OptionError("method lm takes only the linear loss", field="--loss")
    if starts < 1:
        raise OptionError(f"must be at least 1, got {starts}", field="--starts")
    if not 0.0 <= step_tolerance < float("inf"):
        raise OptionError(f"must be a finite number >= 0, got {step_tolerance}", field="step_tolerance")
    options = (loss, loss_scale, method, starts, seed, max_evaluations, ftol, xtol, step_tolerance, progress, t_start)
    if predictor is not None:
        return _calibrate(predictor, scene, mapping, train, holdout, fit, *options)
    if workers is None:
        workers = default_workers(min(len(train), mapping.max_samples or len(train)))
    # (the runtime predictor's own path without friction, its workers included)
    with SequencePredictor(scene, mapping, workers=workers) as predictor:
        return _calibrate(predictor, scene, mapping, train, holdout, fit, *options)


class _Converged(Exception):
    """Raised from the Jacobian when the Gauss–Newton step is below the step tolerance."""

    def __init__(self, y, cost):
        super().__init__()
        self.y, self.cost = y, cost


def _step_in_standard_errors(J, r, y, lower, upper) -> float:
    """``‖J δ‖ / σ`` of the Gauss–Newton step ``δ`` of the linearised residuals ``r + J δ`` from
    ``y`` within the bounds (module docstring), ``σ² = |r|² / (m − p)``."""
    m, p = J.shape
    sigma2 = float(r @ r) / max(m - p, 1)
    if not sigma2 > 0.0:
        return 0.0
    delta = np.linalg.lstsq(J, -r, rcond=None)[0]
    if np.any(y + delta < lower) or np.any(y + delta > upper):
        # (a bound in the way: the step to the bounded minimum; the bounds made a little wider so
        # that a parameter sitting on one stays a feasible start)
        delta = lsq_linear(J, -r, bounds=(np.minimum(lower - y, 0.0), np.maximum(upper - y, 0.0)),
                           method="bvls").x
    return float(np.linalg.norm(J @ delta) / np.sqrt(sigma2))


def _calibrate(predictor, scene, mapping, train, holdout, fit, loss, loss_scale, method, starts, seed,
               max_evaluations, ftol, xtol, step_tolerance, progress, t_start) -> Calibration:
    length = float(predictor.model.length_scale)
    ps = parse_parameters(list(fit) if fit else list(mapping.fit), scene, mapping, predictor.model)
    if mapping.max_samples and len(train) > mapping.max_samples:
        train = train.take(np.unique(np.linspace(0, len(train) - 1, mapping.max_samples).round().astype(int)))
    elements = sorted({e for group in ps.elements for e in group}, key=str)
    column = {e: i for i, e in enumerate(elements)}
    gather = np.zeros((len(elements), len(ps)))
    for j, group in enumerate(ps.elements):
        for e in group:
            gather[column[e], j] = 1.0
    measured = train.markers.reshape(-1)
    counter = {"fun": 0, "jac": 0, "solve_s": 0.0, "derivative_s": 0.0, "newton_iterations": 0}
    last = {}                      # the residuals of the last evaluation, by point

    def values_of(z):
        return ps.values(ps.initial + z * ps.typical)

    def fun(z):
        prediction = predictor.predict(values_of(z), train)
        counter["fun"] += 1
        counter["solve_s"] += prediction.solve_s
        counter["newton_iterations"] += prediction.iterations
        r = prediction.markers.reshape(-1) - measured
        last["z"], last["r"] = z.copy(), r
        if progress:
            progress(f"evaluation {counter['fun']}: train RMSE "
                     f"{1e3 * np.sqrt(np.mean(np.sum(r.reshape(-1, 3) ** 2, 1))):.3f} mm")
        return r

    def jac(z):
        prediction = predictor.predict(values_of(z), train, elements)
        counter["jac"] += 1
        counter["solve_s"] += prediction.solve_s
        counter["newton_iterations"] += prediction.iterations
        counter["derivative_s"] += prediction.derivative_s
        return (prediction.derivatives.reshape(-1, len(elements)) @ gather) * ps.typical

    # a parameter whose derivatives vanish on every sample at the initial values (a tendon that
    # stays slack, a marker offset along an axis nothing turns) is not seen by the data: it keeps
    # its initial value (an optimiser free to move it could wander into a state where it acts)
    first = jac(np.zeros(len(ps)))
    free = np.linalg.norm(first, axis=0) > 0.0
    if not free.any():
        raise OptionError("no fitted parameter changes any predicted marker at the initial values",
                          field="--fit")

    def full(y):
        z = np.zeros(len(ps))
        z[free] = y
        return z

    lower = (ps.lower - ps.initial) / ps.typical
    upper = (ps.upper - ps.initial) / ps.typical

    steps = []                     # the Gauss–Newton step in standard errors at every point

    def reduced_jac(y):
        z = full(y)
        J = (first if not z.any() else jac(z))[:, free]
        if measured_steps and "z" in last and np.array_equal(last["z"], z):
            steps.append(_step_in_standard_errors(J, last["r"], y, lower[free], upper[free]))
            if progress:
                progress(f"Gauss-Newton step {steps[-1]:.3g} standard errors")
            if steps[-1] < step_tolerance:
                raise _Converged(y.copy(), 0.5 * float(last["r"] @ last["r"]))
        return J

    # the statistical stop needs the residuals the Jacobian belongs to (linear loss: robust losses
    # weigh the residuals, and their statistics are not σ²(JᵀJ)⁻¹)
    measured_steps = loss == "linear"
    rng = np.random.default_rng(seed)
    best, runs = None, []
    for start in range(starts):
        if start == 0:
            z0 = np.zeros(len(ps))
        else:           # uniform within the bounds, clipped to a few typical changes of the start
            z0 = np.where(free, rng.uniform(np.maximum(lower, -5.0), np.minimum(upper, 5.0)), 0.0)
        options = dict(jac=reduced_jac, method=method, max_nfev=max_evaluations, x_scale=1.0, ftol=ftol,
                       xtol=xtol)
        if method == "trf":
            options.update(bounds=(lower[free], upper[free]), loss=loss,
                           f_scale=loss_scale if loss_scale is not None else 0.01 * length)
        evaluations = counter["fun"]
        try:
            result = least_squares(lambda y: fun(full(y)), z0[free], **options)
        except _Converged as done:
            result = OptimizeResult(x=done.y, cost=done.cost, nfev=counter["fun"] - evaluations, status=5,
                                    message=f"the Gauss-Newton step is below {step_tolerance:g} standard errors")
        result.x = full(result.x)
        runs.append({"start": start, "cost": float(result.cost), "nfev": int(result.nfev),
                     "status": int(result.status), "message": str(result.message)})
        if progress:
            progress(f"start {start}: cost {result.cost:.6g} after {result.nfev} evaluations ({result.message})")
        if best is None or result.cost < best.cost:
            best = result
    z = best.x
    x = ps.initial + z * ps.typical
    values = ps.values(x)
    final = predictor.predict(values, train, elements)
    J = final.derivatives.reshape(-1, len(elements)) @ gather
    residual = final.markers.reshape(-1) - measured
    se, corr, identifiable, sigma, rank = _statistics(J, residual, ps, x)
    span = ps.upper - ps.lower
    at_bound = (np.abs(x - ps.lower) < 1e-6 * span) | (np.abs(ps.upper - x) < 1e-6 * span)
    train_metrics = error_metrics(final.markers, train.markers, train.patterns, length)
    holdout_metrics = holdout_prediction = None
    if holdout is not None:
        h = predictor.predict(values, holdout)
        holdout_prediction = h.markers
        holdout_metrics = error_metrics(h.markers, holdout.markers, holdout.patterns, length)
    optimiser = {"method": method, "loss": loss, "starts": runs, "best_start": runs.index(
        min(runs, key=lambda r: r["cost"])), "evaluations": counter["fun"], "jacobians": counter["jac"],
                 "newton_iterations": counter["newton_iterations"], "workers": getattr(predictor, "workers", 1),
                 "step_tolerance_se": step_tolerance if measured_steps else 0.0, "steps_se": steps, **rank}
    timings = {"total_s": time.perf_counter() - t_start, "solve_s": counter["solve_s"],
               "derivative_s": counter["derivative_s"]}
    return Calibration(ps, x, se, corr, identifiable, at_bound, values, length, train_metrics, holdout_metrics,
                       final.markers, holdout_prediction, train, holdout, sigma, optimiser, timings)
