"""What the links and the cable routing of a trunk can represent, and how to say it when a
state leaves that: a link turning towards π (the logarithm's branch cut), a link folding
through itself, the holes of a cable piece meeting. The forward solve raises
:class:`Unrepresentable` inside a load stage and reports its message as a ``ConvergenceError``.
"""

from __future__ import annotations

import math

import numpy as np

TURN_LIMIT = 0.9 * math.pi    # a link turning further cannot be represented (the log's branch cut is at π)
COLLAPSE_LIMIT = 1e-6  # a cable piece shorter than this fraction of its rest length: its holes meet
FOLD_LIMIT = 0.1       # a link shorter than this fraction of its rest length has folded through itself
REPRESENTED_TURN = math.pi / 3   # rotation per link the constant-strain links represent well


class Unrepresentable(Exception):
    """Raised inside a stage at a state the links or the cable routing cannot represent (the
    message says why; ``state`` is that state)."""

    def __init__(self, message: str, state=None):
        super().__init__(message)
        self.state = state


def largest_turn(xi: np.ndarray) -> float:
    """The largest rotation (rad) of the links of strains ``ξ``."""
    phi = xi[:, 3:]
    return math.sqrt(float(np.einsum("ij,ij->i", phi, phi).max(initial=0.0)))


def segment_of(trunk, link: int) -> tuple[int, int]:
    """(segment index, links per repetition) of a link."""
    start = 0
    for index, segment in enumerate(trunk.scene.segments):
        end = start + segment.count * segment.elements
        if link < end:
            return index, segment.elements
        start = end
    raise IndexError(link)


def _fitted(trunk, link: int) -> bool:
    """Is the link's energy fitted on a range (a nonlinear entry's)?"""
    return any(energy.fitted and link in energy.links for energy in trunk.links.energies)


def turn_message(trunk, xi: np.ndarray, scale: float, linear: np.ndarray | None) -> str:
    """Which link turns towards π, and how many links per repetition its segment would need to
    turn at most :data:`REPRESENTED_TURN` each. The rotation a repetition needs is estimated as
    the larger of what it turns here (extrapolated from the load factor reached to the full
    load) and what it turns in the linear response to the full load (``linear``, per link)."""
    turns = np.linalg.norm(xi[:, 3:] - trunk.links.rest[:, 3:], axis=1) / max(scale, 1e-12)
    if linear is not None:
        turns = np.maximum(turns, linear)
    k = int(np.argmax(np.linalg.norm(xi[:, 3:], axis=1)))
    segment, elements = segment_of(trunk, k)
    start = sum(s.count * s.elements for s in trunk.scene.segments[:segment])
    count = trunk.scene.segments[segment].count
    needed = turns[start:start + count * elements].reshape(count, elements).sum(1).max()
    links = max(elements + 1, math.ceil(needed / REPRESENTED_TURN))
    spec = trunk.scene.segments[segment]
    if spec.type != "beam":
        repetitions = max(count + 1, math.ceil(count * needed / REPRESENTED_TURN))
        what = f"entry {spec.entry!r}" if spec.entry else spec.type
        turned = math.degrees(float(np.linalg.norm(xi[k, 3:])))
        return (f"link {k} (segment {segment}, {what}) turns {turned:.0f}° at load factor {scale:.3g}: a link's "
                f"rotation must stay below 180°, and a catalogue entry is condensed onto one link per repetition "
                "(its elements cannot be raised); a repetition of the segment turns about "
                f"{math.degrees(needed):.0f}° under this load. Build the segment from a shorter entry repeated more "
                f"often (about {repetitions} repetitions instead of {count}, "
                f"≤ {math.degrees(REPRESENTED_TURN):.0f}° each), or lower the load"
                + ("; where the state leaves the nonlinear entry's fitted range (the out-of-range diagnostics), "
                   "widen the sampled range with `vertebra design … --sampling bending=… --sampling strain=…` or "
                   "let `vertebra prepare` size it from the scene" if _fitted(trunk, k) else ""))
    return (f"link {k} (segment {segment}) turns {math.degrees(float(np.linalg.norm(xi[k, 3:]))):.0f}° at load "
            f"factor {scale:.3g}: the deformation cannot be represented with {elements} link(s) per repetition "
            f"(a link's rotation must stay below 180°); a repetition of the segment turns about "
            f"{math.degrees(needed):.0f}°, so it needs at least {links} links per repetition "
            f"(elements = {links}) to turn ≤ {math.degrees(REPRESENTED_TURN):.0f}° per link")
