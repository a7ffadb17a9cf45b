"""Build backend: setuptools, run on a copy of the sources so that building a wheel or an
sdist leaves nothing (``build/``, ``*.egg-info``) in the source tree.

The repository keeps ``designer/ store/ solver/ cli/`` at its top level; ``pyproject.toml``
maps them to the subpackages of one import package, ``vertebra``. Editable installs run in
place (their metadata directory is git-ignored).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import warnings
from contextlib import contextmanager
from pathlib import Path

from setuptools import build_meta as _setuptools
from setuptools.build_meta import (  # noqa: F401  (re-exported hooks)
    get_requires_for_build_editable,
    prepare_metadata_for_build_editable,
)

SHIPPED = ("pyproject.toml", "README.md", "MANIFEST.in", "tools", "__init__.py", "__main__.py", "cli", "core", "designer", "solver", "store",
           "examples", "docs", "LICENSE")


@contextmanager
def _in_a_copy():
    source = Path.cwd()
    with tempfile.TemporaryDirectory(prefix="vertebra-build-") as tmp:
        for name in SHIPPED:
            path = source / name
            if path.is_dir():
                shutil.copytree(path, Path(tmp) / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
            elif path.exists():
                shutil.copy2(path, Path(tmp) / name)
        os.chdir(tmp)
        try:
            yield
        finally:
            os.chdir(source)


def _absolute(directory: str) -> str:
    return str(Path(directory).resolve())


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):
    wheel_directory = _absolute(wheel_directory)
    metadata_directory = metadata_directory and _absolute(metadata_directory)
    with _in_a_copy():
        return _setuptools.build_wheel(wheel_directory, config_settings, metadata_directory)


def build_sdist(sdist_directory, config_settings=None):
    sdist_directory = _absolute(sdist_directory)
    with _in_a_copy():
        return _setuptools.build_sdist(sdist_directory, config_settings)


def prepare_metadata_for_build_wheel(metadata_directory, config_settings=None):
    metadata_directory = _absolute(metadata_directory)
    with _in_a_copy():
        return _setuptools.prepare_metadata_for_build_wheel(metadata_directory, config_settings)


def get_requires_for_build_wheel(config_settings=None):
    with _in_a_copy():
        return _setuptools.get_requires_for_build_wheel(config_settings)


def get_requires_for_build_sdist(config_settings=None):
    with _in_a_copy():
        return _setuptools.get_requires_for_build_sdist(config_settings)


def build_editable(wheel_directory, config_settings=None, metadata_directory=None):
    with warnings.catch_warnings():
        # setuptools warns that folders named like the package may shadow it; the import
        # package is `vertebra` and no folder of that name exists in the repository
        warnings.filterwarnings("ignore", message="Editable installation")
        return _setuptools.build_editable(wheel_directory, config_settings, metadata_directory)
