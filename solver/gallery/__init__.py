"""Named canonical scenes reused by tests, docs, benchmarks, examples and the demo.

``load(name)`` returns a validated :class:`~vertebra.solver.scene.Scene`; ``path(name)`` the TOML
file (copy it to start a scene of your own); ``names()`` lists them. Scenes live next to this
file as ``<name>.toml``; ``gallery:NAME`` in place of a file name loads one
(:func:`~vertebra.solver.scene.load_scene`).
"""

from __future__ import annotations

from vertebra.solver.scene import Scene, load_scene
from vertebra.solver.scene import gallery_names as names
from vertebra.solver.scene import gallery_path as path

__all__ = ["load", "names", "path"]


def load(name: str) -> Scene:
    return load_scene(path(name))
