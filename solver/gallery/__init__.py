"""Named canonical scenes reused by tests, docs, benchmarks, examples and the demo.

``load(name)`` returns a validated :class:`~solver.scene.Scene`; ``path(name)`` the TOML
file (copy it to start a scene of your own). Scenes live next to this file as ``<name>.toml``.
"""

from __future__ import annotations

from pathlib import Path

from vertebra.solver.scene import Scene, load_scene
from vertebra.store.errors import SceneError

_HERE = Path(__file__).parent


def names() -> list[str]:
    return sorted(p.stem for p in _HERE.glob("*.toml"))


def path(name: str) -> Path:
    candidate = _HERE / f"{name}.toml"
    if not candidate.is_file():
        raise SceneError(f"no gallery scene {name!r}; available: {', '.join(names())}", file="gallery")
    return candidate


def load(name: str) -> Scene:
    return load_scene(path(name))
