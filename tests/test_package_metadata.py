"""What an installed package tells its user: metadata (licence, authors, links) and the way
from any ``--help`` to the documentation it cites."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

from vertebra.cli import main as cli_main

ROOT = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
CITED = re.compile(r"docs/([A-Za-z0-9_.-]+\.(?:md|png))")


def _parsers(parser, prefix=()):
    import argparse

    yield prefix, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, child in action.choices.items():
                yield from _parsers(child, prefix + (name,))


def test_metadata_names_licence_and_authors_and_ships_the_licence():
    project = PYPROJECT["project"]
    assert project["license"] == "MIT" and "MIT License" in (ROOT / "LICENSE").read_text()
    assert project["license-files"] == ["LICENSE"]
    assert project["authors"] and all(a.get("name") or a.get("email") for a in project["authors"])
    for name, url in project.get("urls", {}).items():       # links, when there are any, are links
        assert re.match(r"https?://", url), (name, url)


def test_the_docs_ship_with_the_package():
    shipped = PYPROJECT["tool"]["setuptools"]["package-data"]["vertebra"]
    assert "docs/*.md" in shipped and "docs/*.png" in shipped
    import importlib.util
    spec = importlib.util.spec_from_file_location("build_backend", ROOT / "tools" / "build_backend.py")
    backend = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(backend)
    assert "docs" in backend.SHIPPED


def test_every_cited_document_exists():
    """Help texts and messages cite docs/NAME.md: each one is in docs/ (and so in the package)."""
    cited = set()
    for folder in ("cli", "core", "store", "solver", "designer"):
        for source in (ROOT / folder).rglob("*.py"):
            cited |= set(CITED.findall(source.read_text(encoding="utf-8")))
    cited.discard("NAME.md")                                  # the epilog's placeholder
    assert cited, "no citations found: the pattern is wrong"
    missing = sorted(name for name in cited if not (cli_main.DOCS / name).is_file())
    assert not missing, f"cited but not in {cli_main.DOCS}: {missing}"


@pytest.mark.parametrize("argv", [["--help"], ["catalogue", "--help"], ["catalogue", "verify", "--help"],
                                  ["prepare", "--help"], ["simulate", "--help"]])
def test_help_ends_with_where_the_docs_are(argv, capsys):
    with pytest.raises(SystemExit) as stop:
        cli_main.main(argv)
    assert stop.value.code == 0
    out = capsys.readouterr().out
    assert out.rstrip().endswith(str(cli_main.DOCS)) and (cli_main.DOCS / "scenes.md").is_file()


def test_every_command_cites_the_docs():
    parsers = list(_parsers(cli_main.build_parser()))
    assert len(parsers) > 10
    assert [name for name, p in parsers if p.epilog != cli_main.DOCS_EPILOG] == []
