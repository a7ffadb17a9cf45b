"""CalculiX input decks for a trunk of stacked segments joined by rigid vertebrae.

Units in the deck are mm, N, MPa, t (tonne), s — the inputs here are SI and converted on writing.

* Solid: C3D10 (node order = scikit-fem's tet10 order, tets positively oriented by
  :mod:`ccx.trunk`), one element set and material per segment. Node ids are dense (1 … n): CalculiX
  sizes its arrays by the largest id.
* Materials: ``neo_hookean`` → ``*HYPERELASTIC, NEO HOOKE`` with ``C10 = μ/2``, ``D1 = 2/K``;
  ``svk`` → ``*ELASTIC`` (St Venant–Kirchhoff under NLGEOM).
* Vertebrae: ``*RIGID BODY, NSET=Vj, REF NODE=Rj, ROT NODE=Qj`` over the nodes of both faces the
  vertebra ties (and its cap plugs); ``Rj`` sits at the frame origin ``(0, 0, z_j)``. Vertebra 0
  (the base) has ``Rj`` and ``Qj`` fixed, so their reactions are the base's force and moment.
* Dead forces: ``*CLOAD`` on ``Rj`` (its direction stays fixed under NLGEOM).
* Moments: four "arm" nodes per vertebra, at ``±ℓ e_x`` and ``±ℓ e_y`` from the frame origin,
  belong to its rigid body; dead forces on them form a couple (:func:`ccx.run.arm_forces` builds
  them from the moment and the vertebra's rotation, and :mod:`ccx.run` iterates on that
  rotation). Two things rule out simpler ways: a ``*CLOAD`` on the rot node is no dead moment
  under NLGEOM (the rot node's unknown is the total rotation vector ``w``, so a load ``q`` there
  is the moment ``T(w)⁻ᵀ q``), and CalculiX's rigid-body constraint is linearised without its
  second derivative, so its Newton iterations lose convergence when the forces on a rigid body
  have a large symmetric first moment ``Σ f ⊗ r`` — a pure bending moment through the rot node
  (or a prescribed rotation) stalled near 0.9 rad of tip rotation on 3k–9k-DoF trunks. Bending
  couples made of forces along the vertebra's axis at ``±ℓ`` mirror the face's own bending
  stresses, so at the tip the two first moments cancel; torsion couples have none.
* Chamber pressure: ``*DLOAD`` ``Pk`` on the C3D10 faces of the cavity walls (it follows the
  deformed surface under NLGEOM). The caps lie on the rigid vertebrae: each is closed by a fan of
  extra C3D10 "plug" elements whose nodes all belong to that vertebra's rigid body (a rigid
  motion strains them nowhere) and whose face on the cavity side coincides with the cap, so the
  same follower ``*DLOAD`` carries the cap's load, with its exact area and line of action, to the
  vertebra.
* Gravity: ``*DLOAD, GRAV`` on the segments (mass density per segment); a vertebra's weight is a
  dead force at its frame origin (its centre of mass).
* One ``*STEP`` per load level (loads ramp from the previous level: continuation), output at
  each step's end: displacement of the ref/rot nodes and of the cavity wall nodes, base reactions.
* Increment control (``*CONTROLS, PARAMETERS=TIME INCREMENTATION``): near rigid bodies that carry
  large forces Newton converges only linearly, with bumps (see Moments), typically in 8–13
  iterations. With CalculiX's defaults an increment needing more than 4 iterations never grows
  again, one needing more than 10 shrinks, and two rising residuals after iteration 4 count as
  divergence: a 3-D trunk crawled through 0.008-sized increments for 20 minutes and four
  pressurised slices took 258 s where 50 s do. :data:`INCREMENTATION` lets increments of up to
  16 iterations grow, checks divergence from iteration 16 and allows 60 before a cutback; the
  residual tolerances (what decides the answer) are CalculiX's defaults.
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field

import numpy as np

MM = 1.0e3                  # m -> mm
MPA = 1.0e-6                # Pa -> MPa
DENSITY = 1.0e-12           # kg/m^3 -> t/mm^3
# I_0, I_R, I_P, I_C, I_L, I_G, I_S, I_A of *CONTROLS, PARAMETERS=TIME INCREMENTATION
INCREMENTATION = (16, 24, 9, 60, 30, 16, 0, 8)
ARMS = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0]])   # arm nodes / ℓ


@dataclass(frozen=True)
class Material:
    model: str              # "neo_hookean" | "svk"
    youngs_modulus: float   # Pa
    poisson_ratio: float
    density: float = 0.0    # kg/m^3

    def __post_init__(self):
        if self.model not in MATERIAL_CARDS:
            raise ValueError(f"material model {self.model!r}: expected one of {sorted(MATERIAL_CARDS)}")

    def lines(self) -> list[str]:
        return MATERIAL_CARDS[self.model](self)


def _neo_hookean(m: Material) -> list[str]:
    E, nu = m.youngs_modulus * MPA, m.poisson_ratio
    mu, K = E / (2 * (1 + nu)), E / (3 * (1 - 2 * nu))
    return ["*HYPERELASTIC, NEO HOOKE", f"{mu / 2:.12e}, {2 / K:.12e}"]


def _svk(m: Material) -> list[str]:
    return ["*ELASTIC", f"{m.youngs_modulus * MPA:.12e}, {m.poisson_ratio:.12e}"]


MATERIAL_CARDS = {"neo_hookean": _neo_hookean, "svk": _svk}


@dataclass
class LoadLevel:
    """Loads of one step (absolute values, SI): ``forces`` (3,) at the frame origin and
    ``arm_forces`` (4, 3) on the arm nodes (+x, −x, +y, −y), by vertebra number, in N; ``pressures`` by
    (segment, cavity) in Pa; ``gravity`` in m/s²."""

    forces: dict = field(default_factory=dict)
    arm_forces: dict = field(default_factory=dict)
    pressures: dict = field(default_factory=dict)
    gravity: tuple = (0.0, 0.0, 0.0)


@dataclass
class Deck:
    text: str
    ref_nodes: list                 # vertebra j -> node id of Rj
    arm_length: float               # m
    rot_nodes: list                 # vertebra j -> node id of Qj
    wall_node_ids: np.ndarray       # ids printed for the cavity volumes (1-based trunk node ids)
    n_steps: int


def _fmt_ids(ids, per_line=16) -> list[str]:
    ids = [str(int(i)) for i in ids]
    return [", ".join(ids[i:i + per_line]) + "," for i in range(0, len(ids), per_line)]


def _plugs(trunk, first_node: int, first_element: int):
    """Fan elements closing every cap. Returns (node coordinates (k, 3) m, elements (e, 10) 1-based
    ids, faces [(element id, vertebra, (segment, cavity))], nodes by vertebra)."""
    coords, elements, faces = [], [], []
    by_vertebra = {j: [] for j in range(len(trunk.z))}
    next_node, next_element = first_node, first_element

    def new_node(x):
        nonlocal next_node
        coords.append(x)
        next_node += 1
        return next_node - 1

    for cavity in trunk.cavities:
        for end, sign in (("bottom", -1.0), ("top", 1.0)):
            edges = cavity.rims[end]
            j = cavity.vertebrae[end]
            x = trunk.nodes
            rim = np.unique(edges[:, :2])
            centre = x[rim].mean(axis=0)
            height = np.linalg.norm(x[rim] - centre, axis=1).mean()
            apex = centre + sign * height * np.array([0.0, 0.0, 1.0])
            c, t = new_node(centre), new_node(apex)
            ct = new_node(0.5 * (centre + apex))
            by_vertebra[j] += [c, t, ct]
            for a, b, m in edges:
                corners = [c, a + 1, b + 1]
                pa, pb = x[a], x[b]
                # positive volume: ((a − c) × (b − c))·(apex − c) > 0, else swap a and b
                if np.cross(pa - centre, pb - centre) @ (apex - centre) < 0:
                    corners = [c, b + 1, a + 1]
                    pa, pb = pb, pa
                ca, cb = new_node(0.5 * (centre + pa)), new_node(0.5 * (centre + pb))
                at, bt = new_node(0.5 * (pa + apex)), new_node(0.5 * (pb + apex))
                by_vertebra[j] += [ca, cb, at, bt]
                elements.append([corners[0], corners[1], corners[2], t, ca, m + 1, cb, ct, at, bt])
                faces.append((next_element, (cavity.segment, cavity.index)))
                next_element += 1
    return np.array(coords), np.array(elements, dtype=np.int64), faces, by_vertebra


def write_deck(trunk, materials: list[Material], levels: list[LoadLevel], *, nlgeom: bool = True,
               arm_length: float = 0.01, initial_increment: float = 0.25, min_increment: float = 1e-5,
               max_increments: int = 400, symmetric_xz: bool = False) -> Deck:
    """The input deck of ``trunk`` (:class:`ccx.trunk.TrunkMesh`) with one material per segment
    and one step per load level. ``symmetric_xz`` holds every vertebra in the xz-plane (no y
    translation, rotation about y only): the symmetric path of a problem symmetric about that
    plane, for when CalculiX's Newton iterations fail in the vertebrae's out-of-plane modes."""
    if len(materials) != trunk.n_segments:
        raise ValueError(f"{len(materials)} materials for {trunk.n_segments} segments")
    out = io.StringIO()
    w = out.write
    n = trunk.nodes.shape[0]
    ne = trunk.tets.shape[0]
    plug_x, plug_e, plug_faces, plug_nodes = _plugs(trunk, n + 1, ne + 1)
    n_plug = plug_x.shape[0]
    m1 = len(trunk.z)
    ref = [n + n_plug + 1 + j for j in range(m1)]
    rot = [n + n_plug + 1 + m1 + j for j in range(m1)]
    arms = [[n + n_plug + 1 + 2 * m1 + 4 * j + k for k in range(4)] for j in range(m1)]
    w("** vertebra trunk: segments, rigid vertebrae (mm, N, MPa, t, s)\n*NODE, NSET=NALL\n")
    x = np.concatenate([trunk.nodes, plug_x.reshape(-1, 3)]) * MM
    for i, p in enumerate(x):
        w(f"{i + 1}, {p[0]:.12e}, {p[1]:.12e}, {p[2]:.12e}\n")
    for j in range(m1):
        w(f"{ref[j]}, 0.0, 0.0, {trunk.z[j] * MM:.12e}\n")
    for j in range(m1):
        w(f"{rot[j]}, 0.0, 0.0, {trunk.z[j] * MM:.12e}\n")
    for j in range(m1):
        for k, offset in enumerate(ARMS):
            a = np.array([0.0, 0.0, trunk.z[j]]) + arm_length * offset
            w(f"{arms[j][k]}, {a[0] * MM:.12e}, {a[1] * MM:.12e}, {a[2] * MM:.12e}\n")
    for s in range(trunk.n_segments):
        w(f"*ELEMENT, TYPE=C3D10, ELSET=SEG{s}\n")
        for e in np.flatnonzero(trunk.segment_of_tet == s):
            w(f"{e + 1}, " + ", ".join(str(v + 1) for v in trunk.tets[e]) + "\n")
    if plug_e.size:
        w("*ELEMENT, TYPE=C3D10, ELSET=PLUGS\n")
        for i, el in enumerate(plug_e):
            w(f"{ne + 1 + i}, " + ", ".join(str(v) for v in el) + "\n")
    w("*ELSET, ELSET=SOLID\n" + "\n".join(f"SEG{s}," for s in range(trunk.n_segments)) + "\n")
    for j in range(m1):
        ids = np.concatenate([trunk.face_nodes[j] + 1, np.asarray(plug_nodes[j] + arms[j], dtype=np.int64)])
        w(f"*NSET, NSET=V{j}\n" + "\n".join(_fmt_ids(ids)) + "\n")
    w("*NSET, NSET=REFS\n" + "\n".join(_fmt_ids(ref)) + "\n")
    w("*NSET, NSET=ROTS\n" + "\n".join(_fmt_ids(rot)) + "\n")
    w(f"*NSET, NSET=BASE\n{ref[0]}, {rot[0]}\n")
    wall_ids = np.unique(np.concatenate([c.wall_nodes for c in trunk.cavities])) + 1 if trunk.cavities else \
        np.zeros(0, dtype=np.int64)
    if wall_ids.size:
        w("*NSET, NSET=WALLS\n" + "\n".join(_fmt_ids(wall_ids)) + "\n")
    for s, mat in enumerate(materials):
        w(f"*MATERIAL, NAME=M{s}\n" + "\n".join(mat.lines()) + "\n")
        w(f"*DENSITY\n{mat.density * DENSITY:.12e}\n")
        w(f"*SOLID SECTION, ELSET=SEG{s}, MATERIAL=M{s}\n")
    if plug_e.size:
        w("*MATERIAL, NAME=PLUG\n*ELASTIC\n1.0, 0.3\n*SOLID SECTION, ELSET=PLUGS, MATERIAL=PLUG\n")
    for j in range(m1):
        w(f"*RIGID BODY, NSET=V{j}, REF NODE={ref[j]}, ROT NODE={rot[j]}\n")
    w(f"*BOUNDARY\n{ref[0]}, 1, 3\n{rot[0]}, 1, 3\n")
    if symmetric_xz:
        w("".join(f"{ref[j]}, 2, 2\n{rot[j]}, 1, 1\n{rot[j]}, 3, 3\n" for j in range(1, m1)))
    faces_of = {(c.segment, c.index): c for c in trunk.cavities}
    for k, level in enumerate(levels):
        w(f"*STEP{', NLGEOM' if nlgeom else ''}, INC={max_increments}\n")
        if nlgeom:
            w("*CONTROLS, PARAMETERS=TIME INCREMENTATION\n" + ", ".join(map(str, INCREMENTATION)) + "\n")
        w("*STATIC\n")
        w(f"{initial_increment}, 1.0, {min_increment}, 1.0\n" if nlgeom else "1.0, 1.0\n")
        loads = []
        for j in range(1, m1):
            arm = np.asarray(level.arm_forces.get(j, np.zeros((4, 3))), float)
            f = np.asarray(level.forces.get(j, np.zeros(3)), float) - arm.sum(axis=0)
            loads += [f"{ref[j]}, {d + 1}, {f[d]:.12e}" for d in range(3)]
            loads += [f"{arms[j][k]}, {d + 1}, {arm[k, d]:.12e}" for k in range(4) for d in range(3)]
        w("*CLOAD\n" + "\n".join(loads) + "\n")
        if faces_of:
            w("*DLOAD\n")
            for key, cavity in faces_of.items():
                p = level.pressures.get(key, 0.0) * MPA
                for tet, face in cavity.faces:
                    w(f"{tet + 1}, P{face}, {p:.12e}\n")
            for element, key in plug_faces:
                w(f"{element}, P1, {level.pressures.get(key, 0.0) * MPA:.12e}\n")
        g = np.asarray(level.gravity, float) * MM
        if np.any(g != 0) or k > 0:
            size = np.linalg.norm(g)
            direction = g / size if size > 0 else np.array([0.0, 0.0, -1.0])
            w(f"*DLOAD\nSOLID, GRAV, {size:.12e}, {direction[0]:.12e}, {direction[1]:.12e}, {direction[2]:.12e}\n")
        w("*NODE PRINT, NSET=REFS\nU\n*NODE PRINT, NSET=ROTS\nU\n*NODE PRINT, NSET=BASE, TOTALS=NO\nRF\n")
        if wall_ids.size:
            w("*NODE PRINT, NSET=WALLS\nU\n")
        w("*END STEP\n")
    return Deck(text=out.getvalue(), ref_nodes=ref, arm_length=arm_length, rot_nodes=rot, wall_node_ids=wall_ids, n_steps=len(levels))
