"""Read CalculiX ``.dat`` node prints (written by :mod:`ccx.deck`) back into SI arrays.

A ``*NODE PRINT`` block starts with a header such as
``displacements (vx,vy,vz) for set REFS and time  0.1000000E+01`` followed by ``node v1 v2 v3``
rows. CalculiX prints every converged increment; the time is the total time, so step ``k``
(1-based) ends at time ``k``. Values carry 7 significant digits.
"""

from __future__ import annotations

import re

import numpy as np

from benchmarks.ccx.deck import MM

_HEADER = re.compile(r"^\s*(displacements|forces)\s+\(\w+,\w+,\w+\)\s+for set\s+(\S+)\s+and time\s+(\S+)")


def read_dat(path) -> list[dict]:
    """All print blocks: ``[{"kind", "set", "time", "ids" (k,), "values" (k, 3)}]`` in file order."""
    blocks, current = [], None
    with open(path) as handle:
        for line in handle:
            match = _HEADER.match(line)
            if match:
                current = {"kind": match.group(1), "set": match.group(2), "time": float(match.group(3)),
                           "ids": [], "values": []}
                blocks.append(current)
                continue
            parts = line.split()
            if current is not None and len(parts) == 4 and parts[0].isdigit():
                current["ids"].append(int(parts[0]))
                current["values"].append([float(v) for v in parts[1:]])
            elif current is not None and parts:
                current = None
    for b in blocks:
        b["ids"] = np.array(b["ids"], dtype=np.int64)
        b["values"] = np.array(b["values"], dtype=float).reshape(-1, 3)
    return blocks


def step_results(blocks: list[dict], deck, tol: float = 1e-6) -> dict:
    """Results at the end of each completed step: ``{step (1-based): {...}}`` with, in SI,
    ``translation`` (m+1, 3) m and ``rotation`` (m+1, 3) rad of every vertebra (rot-node
    rotation vectors), ``base_force`` (3,) N and ``base_rot_reaction`` (3,) N m (the rot node's
    reaction; a moment while the base does not rotate), ``walls`` {node id: (3,) m} if printed;
    plus the largest time reached (``last_time``: a step that stopped early ends before its
    integer time)."""
    out = {"steps": {}, "last_time": max((b["time"] for b in blocks), default=0.0)}

    for b in blocks:
        step = int(round(b["time"]))
        if step < 1 or abs(b["time"] - step) > tol:
            continue
        entry = out["steps"].setdefault(step, {})
        values = dict(zip(b["ids"].tolist(), b["values"]))
        if b["set"] == "REFS":
            entry["translation"] = np.array([values[n] for n in deck.ref_nodes]) / MM
        elif b["set"] == "ROTS":
            entry["rotation"] = np.array([values[n] for n in deck.rot_nodes])
        elif b["set"] == "BASE":
            entry["base_force"] = values[deck.ref_nodes[0]].copy()
            entry["base_rot_reaction"] = values[deck.rot_nodes[0]] / MM
        elif b["set"] == "WALLS":
            entry["walls"] = (b["ids"], b["values"] / MM)
    complete = {k: v for k, v in out["steps"].items() if {"translation", "rotation"} <= set(v)}
    out["steps"] = complete

    return out
