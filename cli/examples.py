"""``vertebra examples DIR`` copies the example scripts, trajectories and sweep specs that
ship with the package into ``DIR``; ``vertebra examples --list`` lists them.

Nothing is overwritten: when a file to be written already exists the command writes
nothing and exits 2 naming it.
"""

from __future__ import annotations

import shutil
import sys
from importlib import resources
from pathlib import Path

from vertebra.core.errors import OptionError

SHIPPED_SUFFIXES = (".py", ".csv", ".toml", ".md", ".json", "LICENSE")   # LICENSE: a data set's licence


def add_arguments(parser) -> None:
    parser.add_argument("directory", nargs="?", metavar="DIR", help="where to copy the examples (created)")
    parser.add_argument("--list", action="store_true", help="list the examples instead of copying them")


def example_files() -> list[tuple[str, object]]:
    """``(relative path, resource)`` of every shipped example file, sorted."""
    root = resources.files("vertebra") / "examples"
    found = []

    def walk(folder, prefix):
        for item in folder.iterdir():
            if item.is_dir():
                if item.name != "__pycache__":
                    walk(item, f"{prefix}{item.name}/")
            elif item.name.endswith(SHIPPED_SUFFIXES):
                found.append((f"{prefix}{item.name}", item))

    walk(root, "")
    return sorted(found, key=lambda pair: pair[0])


def run(args) -> int:
    files = example_files()
    if args.list:
        for name, _ in files:
            print(name)
        return 0
    if args.directory is None:
        raise OptionError("name a directory to copy the examples into (or --list them)", field="DIR")
    target = Path(args.directory)
    if target.exists() and not target.is_dir():
        raise OptionError(f"{target}: exists and is not a directory", field="DIR")
    if not target.parent.is_dir():
        raise OptionError(f"{target}: directory {str(target.parent)!r} does not exist", field="DIR")
    existing = [name for name, _ in files if (target / name).exists()]
    if existing:
        which = f"{target / existing[0]}" + (f" and {len(existing) - 1} more files" if len(existing) > 1 else "")
        raise OptionError(f"{which} already exist{'s' if len(existing) == 1 else ''}; vertebra examples does "
                          f"not overwrite files: choose a new directory or move them away", field="DIR")
    for name, resource in files:
        destination = target / name
        destination.parent.mkdir(parents=True, exist_ok=True)
        with resources.as_file(resource) as source:
            shutil.copyfile(source, destination)
    print(f"copied {len(files)} example files to {target} (see {target / 'README.md'})", file=sys.stderr)
    return 0
