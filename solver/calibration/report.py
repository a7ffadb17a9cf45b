"""What a calibration hands back: the calibrated scene, a JSON document, a Markdown report and
pictures (docs/calibration.md).

* :func:`calibrated_scene_toml` — the scene file with the fitted values in place: moduli
  scaled, hole angles and radii corrected, the tendons' spring rates and pretensions, the
  base pose and gravity expressed in the measurement frame, one effector per marker (a
  negative pretension is a tendon slack by ``−P/k`` at zero stroke).
* :func:`calibration_document` — the ``vertebra calibrate --json`` document.
* :func:`markdown_report`, :func:`write_plots` — for people.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np

from vertebra import __version__
from vertebra.core.lie import qexp, qmul, so3_exp
from vertebra.solver.scene import scene_toml

__all__ = ["calibrated_scene_toml", "calibration_document", "markdown_report", "write_plots"]


def _parameters(cal) -> list:
    ps = cal.parameters
    out = []
    for i, name in enumerate(ps.names):
        se = cal.standard_errors[i]
        out.append({"name": name, "value": float(cal.x[i]), "standard_error": None if np.isnan(se) else float(se),
                    "unit": ps.units()[i], "initial": float(ps.initial[i]), "lower": float(ps.lower[i]),
                    "upper": float(ps.upper[i]), "identifiable": bool(cal.identifiable[i]),
                    "at_bound": bool(cal.at_bound[i])})
    return out


def _elements(cal, scene, mapping) -> dict:
    v = cal.values
    index = {c.name: i for i, c in enumerate(scene.cables)}
    return {"stiffness_scale": {str(i): float(s) for i, s in enumerate(v.stiffness)},
            "cables": {c.name: {"angle_deg": math.degrees(c.angle + da), "radius": c.radius + dr}
                       for c, da, dr in zip(scene.cables, v.angle, v.radius)},
            "tendons": {a.cable: {name: float(getattr(v, kind)[index[a.cable]])
                                  for name, kind in (("stiffness", "cable_stiffness"), ("pretension", "pretension"),
                                                     ("friction", "friction"), ("backlash", "backlash"),
                                                     ("backlash_rate", "backlash_rate"),
                                                     ("entry_friction", "entry_friction"), ("lag", "lag"))}
                        for a in mapping.actuators},
            "frame": {"position": v.frame[:3].tolist(), "rotation_vector": v.frame[3:].tolist()},
            "markers": {m.name: {"vertebra": m.vertebra, "offset": o.tolist()}
                        for m, o in zip(mapping.markers, v.marker)}}


def calibration_document(cal, scene, mapping, sources: dict | None = None) -> dict:
    """The JSON document: metrics (``train``, ``holdout``: ``rmse_m``, ``rmse_pct_length``, …),
    parameters with standard errors, the correlation matrix, every element's value, diagnostics."""
    unidentifiable = [p["name"] for p in _parameters(cal) if not p["identifiable"]]
    return {"vertebra_version": __version__,
            "sources": dict(sources or {}),
            "length_m": cal.length,
            "train": cal.train,
            "holdout": cal.holdout,
            "parameters": _parameters(cal),
            "unidentifiable": unidentifiable,
            "correlation": {"names": list(cal.parameters.names),
                            "matrix": [[None if np.isnan(c) else float(c) for c in row] for row in cal.correlation]},
            "residual_sigma_m": cal.sigma,
            "values": _elements(cal, scene, mapping),
            "optimiser": cal.optimiser,
            "timing": cal.timings}


def _compose_base(scene, frame):
    """Base pose of the scene in the measurement frame: ``T_frame · T_base``; and the frame's
    rotation matrix."""
    Rf = so3_exp(frame[3:])
    position = Rf @ np.asarray(scene.base_position, float) + frame[:3]
    quaternion = qmul(qexp(frame[3:]), np.asarray(scene.base_quaternion, float))
    return position, quaternion, Rf


def calibrated_scene_toml(cal, scene, mapping) -> str:
    """The scene file with the calibrated values (module docstring). The scene's own TOML is
    the starting point, so that every field it had is kept."""
    data = tomllib.loads(Path(scene.source).read_text(encoding="utf-8"))
    v = cal.values
    for table, seg, scale in zip(data.get("segment", []), scene.segments, v.stiffness):
        if scale != 1.0:
            table["youngs_modulus"] = float(seg.youngs_modulus * scale)
            if "shear_modulus" in table:
                table["shear_modulus"] = float(seg.shear_modulus * scale)
    names = [c.name for c in scene.cables]
    driven = {a.cable for a in mapping.actuators}
    for table, cable, da, dr in zip(data.get("cable", []), scene.cables, v.angle, v.radius):
        table.pop("angle", None)
        table["angle_deg"] = math.degrees(cable.angle + da)
        table["radius"] = float(cable.radius + dr)
        if cable.name in driven:
            i = names.index(cable.name)
            table.pop("axial_stiffness", None)
            table.pop("free_length", None)
            table["stiffness"] = float(v.cable_stiffness[i])
            table["pretension"] = float(v.pretension[i])
            if v.friction[i] or "friction" in table:
                table["friction"] = float(v.friction[i])
    position, quaternion, Rf = _compose_base(scene, v.frame)
    data["base"] = {"position": position.tolist(), "quaternion": quaternion.tolist()}
    if scene.gravity is not None:
        data["gravity"] = {"vector": (Rf @ np.asarray(scene.gravity)).tolist()}
    for load in data.get("load", []):
        if load.get("follower", False):          # (in the vertebra's axes: no frame to turn)
            continue
        for key in ("force", "moment"):
            if key in load:
                load[key] = (Rf @ np.asarray(load[key], float)).tolist()
    effectors = [e for e in data.get("effector", []) if e.get("name") not in {m.name for m in mapping.markers}]
    for e in effectors:
        if "target" in e:
            e["target"] = ((Rf @ np.asarray(e["target"], float)) + (0.0 if "axis" in e else v.frame[:3])).tolist()
        if "axis" in e:
            e["axis"] = (Rf @ np.asarray(e["axis"], float)).tolist()
    for m, offset in zip(mapping.markers, v.marker):
        effectors.append({"name": m.name, "vertebra": m.vertebra, "offset": offset.tolist()})
    data["effector"] = effectors
    header = (f"{scene.name or Path(scene.source).stem}: calibrated by vertebra {__version__} "
              f"(held-out tip RMSE {_mm(cal.holdout, 'rmse_m')}, train {_mm(cal.train, 'rmse_m')}); "
              "positions in the measurement frame")
    if v.backlash.any():
        # (a property of the command path, not of the robot: the runtime takes strokes)
        header += ("\nthe calibration's transmission play (backlash, mm), to apply to the commands before "
                   "they become strokes: " + ", ".join(f"{c.name} {1e3 * b:.4g}" for c, b in zip(scene.cables, v.backlash)
                                                      if b))
    if v.backlash_rate.any():
        header += ("\nthe play grows with the tendon's tension (backlash_rate, mm/N): "
                   + ", ".join(f"{c.name} {1e3 * b:.4g}" for c, b in zip(scene.cables, v.backlash_rate) if b))
    if v.entry_friction.any():
        header += ("\na released tendon keeps up to this tension, held by the friction at its entry (N): "
                   + ", ".join(f"{c.name} {f:.4g}" for c, f in zip(scene.cables, v.entry_friction) if f))
    if v.lag.any():
        header += ("\nthe strokes follow the commands with a lag (time constant, s): "
                   + ", ".join(f"{c.name} {t:.4g}" for c, t in zip(scene.cables, v.lag) if t))
    ordered = {k: data[k] for k in data if not isinstance(data[k], (dict, list))}
    ordered.update({k: data[k] for k in data if isinstance(data[k], (dict, list))})
    return scene_toml(ordered, header)


def _mm(metrics, key) -> str:
    return "n/a" if metrics is None else f"{1e3 * metrics[key]:.2f} mm"


def markdown_report(cal, scene, mapping, sources: dict | None = None, pictures: dict | None = None) -> str:
    """A Markdown report of a calibration (metrics, parameters, correlations, pictures)."""
    lines = [f"# Calibration of {scene.name or scene.source}", ""]
    for key, value in (sources or {}).items():
        lines.append(f"* {key}: `{value}`")
    lines += [f"* trunk length (the reference of %): {1e3 * cal.length:.2f} mm",
              f"* optimiser: {cal.optimiser['method']}, loss {cal.optimiser['loss']}, "
              f"{len(cal.optimiser['starts'])} start(s), {cal.optimiser['evaluations']} evaluations, "
              f"{cal.optimiser['jacobians']} Jacobians; {cal.timings['total_s']:.1f} s", ""]
    lines += ["## Tip error", "",
              "| samples | n | RMSE | mean | median | p95 | max | RMSE, offset removed |",
              "|---|---|---|---|---|---|---|---|"]
    for label, m in (("train", cal.train), ("held-out", cal.holdout)):
        if m is None:
            continue
        cells = [f"{1e3 * m[k + '_m']:.2f} mm ({m[k + '_pct_length']:.2f} %)" for k in ("rmse", "mean", "median",
                                                                                      "p95", "max")]
        o = m["offset_removed"]
        lines.append(f"| {label} | {m['n']} | " + " | ".join(cells)
                     + f" | {1e3 * o['rmse_m']:.2f} mm ({o['rmse_pct_length']:.2f} %) |")
    lines.append("")
    for label, m in (("train", cal.train), ("held-out", cal.holdout)):
        if m is None:
            continue
        lines += [f"### Per pattern ({label})", "", "| pattern | n | RMSE (mm) | RMSE, offset removed (mm) | max (mm) |",
                  "|---|---|---|---|---|"]
        for name, p in m["patterns"].items():
            lines.append(f"| {name} | {p['n']} | {1e3 * p['rmse_m']:.2f} | {1e3 * p['offset_removed_rmse_m']:.2f} "
                         f"| {1e3 * p['max_m']:.2f} |")
        lines.append("")
    lines += ["## Parameters", "",
              f"Standard errors from σ² (JᵀJ)⁻¹ with σ = {1e3 * cal.sigma:.3f} mm per coordinate (the residual's "
              "spread; residuals that are correlated along a trajectory make these optimistic).", "",
              "| parameter | value | standard error | unit | initial | bounds | identifiable |", "|---|---|---|---|---|---|---|"]
    for p in _parameters(cal):
        se = "—" if p["standard_error"] is None else f"{p['standard_error']:.4g}"
        ident = "yes" if p["identifiable"] else "**no**"
        bound = " (at bound)" if p["at_bound"] else ""
        lines.append(f"| {p['name']} | {p['value']:.6g}{bound} | {se} | {p['unit']} | {p['initial']:.6g} | "
                     f"[{p['lower']:.4g}, {p['upper']:.4g}] | {ident} |")
    unseen = [p["name"] for p in _parameters(cal) if not p["identifiable"]]
    lines += ["", ("The data cannot identify: " + ", ".join(unseen) + " (a standard error beyond half the bound "
                   "interval, or a direction the data do not see; fix them or tie them to others).") if unseen
              else "Every parameter is identifiable from these data.", ""]
    names, corr = cal.parameters.names, cal.correlation
    strong = [(names[i], names[j], corr[i, j]) for i in range(len(names)) for j in range(i + 1, len(names))
              if np.isfinite(corr[i, j]) and abs(corr[i, j]) > 0.9]
    lines += ["### Strong correlations (|r| > 0.9)", ""]
    lines += [f"* {a} ~ {b}: {r:+.3f}" for a, b, r in strong] or ["none"]
    lines.append("")
    if pictures:
        lines += ["## Pictures", ""]
        for title, path in pictures.items():
            lines += [f"![{title}]({path})", ""]
    return "\n".join(lines)


def write_plots(cal, directory) -> dict:
    """Measured vs predicted markers in 3-D, the error histogram, the error per pattern and
    the residual against actuation; returns {title: file name}."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    sets = [("train", cal.train_samples, cal.train_prediction)]
    if cal.holdout_samples is not None:
        sets.append(("held-out", cal.holdout_samples, cal.holdout_prediction))
    files = {}

    fig = plt.figure(figsize=(6 * len(sets), 5.5))
    for k, (label, samples, predicted) in enumerate(sets):
        ax = fig.add_subplot(1, len(sets), k + 1, projection="3d")
        m, p = 1e3 * samples.markers.reshape(-1, 3), 1e3 * predicted.reshape(-1, 3)
        ax.scatter(*m.T, s=4, c="k", label="measured")
        ax.scatter(*p.T, s=4, c="tab:red", label="predicted")
        for a, b in zip(m[::5], p[::5]):
            ax.plot(*np.stack([a, b]).T, c="tab:gray", lw=0.5)
        ax.set_title(f"{label} markers (mm)")
        ax.legend(loc="upper left")
    files["measured vs predicted markers"] = _save(fig, directory / "markers_3d.png", plt)

    fig, ax = plt.subplots(figsize=(6, 4))
    for label, samples, predicted in sets:
        e = 1e3 * np.linalg.norm(predicted - samples.markers, axis=-1).reshape(-1)
        ax.hist(e, bins=40, alpha=0.6, label=f"{label} (RMSE {np.sqrt(np.mean(e ** 2)):.2f} mm)")
    ax.set_xlabel("marker error (mm)")
    ax.set_ylabel("samples")
    ax.legend()
    files["error histogram"] = _save(fig, directory / "error_histogram.png", plt)

    patterns = [(label, name, 1e3 * p["rmse_m"]) for label, m in (("train", cal.train), ("held-out", cal.holdout))
                if m is not None for name, p in m["patterns"].items()]
    fig, ax = plt.subplots(figsize=(8, max(3.0, 0.18 * len(patterns))))
    colours = {"train": "tab:blue", "held-out": "tab:orange"}
    ax.barh(range(len(patterns)), [r for _, _, r in patterns], color=[colours[l] for l, _, _ in patterns])
    ax.set_yticks(range(len(patterns)), [f"{n} ({l})" for l, n, _ in patterns], fontsize=6)
    ax.invert_yaxis()
    ax.set_xlabel("RMSE (mm)")
    files["error per pattern"] = _save(fig, directory / "error_per_pattern.png", plt)

    fig, ax = plt.subplots(figsize=(6, 4))
    for label, samples, predicted in sets:
        e = 1e3 * np.linalg.norm(predicted - samples.markers, axis=-1).reshape(len(samples), -1).max(axis=1)
        ax.scatter(1e3 * samples.commands.max(axis=1), e, s=4, label=label)
    ax.set_xlabel("largest pull command (mm)")
    ax.set_ylabel("marker error (mm)")
    ax.legend()
    files["residual vs actuation"] = _save(fig, directory / "residual_vs_actuation.png", plt)
    return files


def _save(fig, path, plt) -> str:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path.name
