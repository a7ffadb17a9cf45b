"""Reference models for verification (tests and benchmarks; not part of the installed package): a
full FE model of a chain of segments joined by rigid vertebrae, and the same chain built from
condensed compliances.

Both are linear. The full model is ONE assembled FE system: the interior DoFs of
every segment plus one shared 6-DoF frame per vertebra (frame 0 clamped); each
end face follows its vertebra's frame rigidly (``u_face = T q``). Static
condensation is exact for a linear problem, so the condensed chain must agree
with it to solver round-off — ``tests/test_condensation.py`` holds both (and the
runtime solver) to 1e-6.
"""

from __future__ import annotations

import numpy as np

from vertebra.core.lie import hat
from vertebra.designer.fem import SegmentFE, face_load


def transport(d) -> np.ndarray:
    """H: motion of a frame at offset ``d`` from frame a when a moves rigidly by ``[t; θ]``
    (``t_b = t + θ × d``)."""
    H = np.eye(6)
    H[:3, 3:] = -hat(np.asarray(d, dtype=float))
    return H


def chain_fe_solve(fes: list[SegmentFE], tip_wrench, pressures=None) -> dict:
    """Full FE solution of the chain ``fes[0] .. fes[-1]`` (bottom to top), frame 0 clamped,
    ``tip_wrench`` (6,) on the last frame (at its origin, global axes), ``pressures[s]``
    the cavity pressures of segment ``s``. Returns frame motions (m, 6) of frames 1..m
    and the cavity volume growths per segment."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    m = len(fes)
    pressures = [np.zeros(fe.n_cavities) if pressures is None else np.asarray(pressures[s], float)
                 for s, fe in enumerate(fes)]
    interiors = [fe.interior() for fe in fes]
    sizes = [i.size for i in interiors]
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    n_int = int(offsets[-1])
    n = n_int + 6 * m
    rhs = np.zeros(n)

    def frame_cols(frame):                # global columns of frame ``frame`` (1..m), None if clamped
        return None if frame == 0 else n_int + 6 * (frame - 1) + np.arange(6)

    rows_all, cols_all, vals_all = [], [], []

    def add(rows, cols, M):
        M = sp.coo_matrix(M)
        rows_all.append(rows[M.row]), cols_all.append(cols[M.col]), vals_all.append(M.data)

    for s, fe in enumerate(fes):
        i = interiors[s]
        gi = offsets[s] + np.arange(i.size)
        K = fe.K
        maps = {}
        for name, frame in (("bottom", s), ("top", s + 1)):
            face = fe.faces[name]
            maps[name] = (frame_cols(frame), face)
        add(gi, gi, K[i][:, i])
        for name, (cols, face) in maps.items():
            if cols is None:
                continue
            Kif = sp.csr_matrix(K[i][:, face["dofs"]] @ face["T"])
            add(gi, cols, Kif)
            add(cols, gi, Kif.T)
            for name2, (cols2, face2) in maps.items():
                if cols2 is None:
                    continue
                add(cols, cols2, face["T"].T @ (K[face["dofs"]][:, face2["dofs"]] @ face2["T"]))
        p = pressures[s]
        for k in range(fe.n_cavities):
            rhs[gi] += p[k] * fe.cavity_loads[k][i]
        for name, (cols, face) in maps.items():
            if cols is not None:
                rhs[cols] += face_load(fe, name, p)
    rhs[frame_cols(m)] += np.asarray(tip_wrench, float)
    A = sp.csc_matrix((np.concatenate(vals_all), (np.concatenate(rows_all), np.concatenate(cols_all))),
                      shape=(n, n))
    x = splu(A, permc_spec="MMD_AT_PLUS_A").solve(rhs)
    frames = x[n_int:].reshape(m, 6)
    volumes = []
    for s, fe in enumerate(fes):
        i = interiors[s]
        u_i = x[offsets[s]:offsets[s + 1]]
        q = {"bottom": np.zeros(6) if s == 0 else frames[s - 1], "top": frames[s]}
        growth = []
        for k in range(fe.n_cavities):
            unit = np.zeros(fe.n_cavities)
            unit[k] = 1.0
            g = fe.cavity_loads[k][i] @ u_i + sum(face_load(fe, name, unit) @ q[name] for name in q)
            growth.append(g)
        volumes.append(np.array(growth))
    return {"frames": frames, "volume_growth": volumes, "dofs": n}


def chain_condensed_solve(compliances: list[np.ndarray], lengths: list[float], tip_wrench,
                          pressures=None) -> dict:
    """The same chain from condensed (6+n)×(6+n) compliances: link energy ½ δᵀ K δ with
    ``δ = q_b − H q_a − G p`` (pressure shifts the rest pose by G p, see docs/catalogue.md)."""
    m = len(compliances)
    Kg = np.zeros((6 * m, 6 * m))
    f = np.zeros(6 * m)
    links = []
    for s, (Cfull, L) in enumerate(zip(compliances, lengths)):
        C, G, V = Cfull[:6, :6], Cfull[:6, 6:], Cfull[6:, 6:]
        K = np.linalg.inv(C)
        H = transport([0.0, 0.0, L])
        p = np.zeros(G.shape[1]) if pressures is None else np.asarray(pressures[s], float)
        B = np.hstack([-H, np.eye(6)])                       # δ = B [q_a; q_b]
        Kl = B.T @ K @ B
        fl = B.T @ (K @ (G @ p))
        idx = np.concatenate([(s - 1) * 6 + np.arange(6) if s > 0 else np.array([], int), s * 6 + np.arange(6)])
        local = slice(6, 12) if s == 0 else slice(0, 12)
        Kg[np.ix_(idx, idx)] += Kl[local, local]
        f[idx] += fl[local]
        links.append((K, G, V, H, p))
    f[-6:] += np.asarray(tip_wrench, float)
    q = np.linalg.solve(Kg, f).reshape(m, 6)
    volumes = []
    for s, (K, G, V, H, p) in enumerate(links):
        qa = np.zeros(6) if s == 0 else q[s - 1]
        w = K @ (q[s] - H @ qa - G @ p)                      # elastic wrench carried at b
        volumes.append(G.T @ w + V @ p)
    return {"frames": q, "volume_growth": volumes}
