"""``vertebra`` entry point. One module per subcommand, each with
``add_arguments(parser)`` and ``run(args) -> int``; heavy imports live inside ``run``.

Exit codes: 0 success; 1 solved but not converged or target not reached; 2 bad input
(the message names the file, the field and the reason); 141 (as for SIGPIPE) when the
reader of stdout went away, e.g. ``vertebra simulate … | head``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import importlib
import os
import sys

from vertebra import __version__
from vertebra.core.errors import (CatalogueError, GeometryError, InputError, OptionError, PlausibilityWarning,
                                  VertebraError)

# name -> (module, one-line help). Adding a subcommand touches this table and its module.
SUBCOMMANDS = {
    "simulate": ("vertebra.cli.simulate", "forward quasi-static equilibrium of a scene"),
    "invert": ("vertebra.cli.invert", "actuation that brings effectors to targets"),
    "design": ("vertebra.cli.design", "mesh, solve and condense one segment into the catalogue"),
    "sweep": ("vertebra.cli.sweep", "design-space sweep into the catalogue"),
    "prepare": ("vertebra.cli.prepare", "design only the entries a scene's design segments miss"),
    "catalogue": ("vertebra.cli.catalogue", "list, show, verify, merge, export catalogue entries"),
    "workspace": ("vertebra.cli.workspace", "reachable effector positions over sampled actuations"),
    "calibrate": ("vertebra.cli.calibrate", "fit a scene's parameters to measured static samples"),
    "examples": ("vertebra.cli.examples", "copy the example scripts, trajectories and sweep specs into DIR"),
    "demo": ("vertebra.cli.demo", "the main job on an embedded default, end to end"),
}

BROKEN_PIPE = 141

def _silence_stdout() -> None:
    """Point stdout at /dev/null so that the interpreter's final flush into the closed pipe
    raises nothing (the recipe of Python's signal documentation)."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):   # stdout without a file descriptor (captured in tests)
        pass

#: the documentation's folder: the repository's docs/, installed as vertebra/docs (package data)
DOCS = Path(__file__).resolve().parent.parent / "docs"
DOCS_EPILOG = f"Documentation (docs/NAME.md in the help texts): {DOCS}"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="vertebra",
        description="Model and control continuum robots with rigid vertebrae: design segments (gmsh + "
                    "scikit-fem) into an HDF5 catalogue, simulate trunks forward, invert them for actuation.",
        epilog=DOCS_EPILOG)
    parser.add_argument("--version", action="version", version=f"vertebra {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        module = importlib.import_module(module_name)
        p = sub.add_parser(name, help=help_text, description=help_text)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    _cite_docs(parser)
    return parser


def _cite_docs(parser: argparse.ArgumentParser) -> None:
    """Every command's and subcommand's --help ends by saying where docs/NAME.md is (the docs
    ship inside the installed package)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                child.epilog = child.epilog or DOCS_EPILOG
                _cite_docs(child)

def _one_line_warnings(command: str) -> None:
    """Print each Python warning as one line on stderr, ``vertebra COMMAND: warning: …``."""
    import warnings

    def show(message, category, filename, lineno, file=None, line=None):
        kind = "" if issubclass(category, (PlausibilityWarning, UserWarning)) else f"{category.__name__}: "
        text = " ".join(str(message).split())
        print(f"vertebra {command}: warning: {kind}{text}", file=sys.stderr if file is None else file)

    warnings.showwarning = show


def _refuse_nul_bytes(args) -> None:
    """An argument with a NUL byte names no file and no value (a shell cannot pass one; a
    caller of ``main(argv)`` can): an OptionError naming the option."""
    for name, value in vars(args).items():
        for item in value if isinstance(value, list) else [value]:
            if isinstance(item, str) and "\x00" in item:
                option = "--" + name.replace("_", "-") if not name.startswith("_") else name
                raise OptionError(f"{item!r}: an argument cannot contain a NUL byte", field=option)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    _one_line_warnings(args.command)
    # lazy: importing designer.threads loads the designer package; the parser and --help do without it
    from vertebra.designer.threads import pin_blas_threads

    pin_blas_threads()      # one BLAS/OpenMP thread per process (designer/threads.py says why)
    try:
        _refuse_nul_bytes(args)
        code = int(args._run(args))
        sys.stdout.flush()          # a closed pipe shows here, not at interpreter exit
        return code
    except BrokenPipeError:
        _silence_stdout()
        return BROKEN_PIPE
    except (InputError, CatalogueError, GeometryError) as error:
        print(f"vertebra {args.command}: error: {error}", file=sys.stderr)
        return 2
    except VertebraError as error:
        print(f"vertebra {args.command}: {type(error).__name__}: {error}", file=sys.stderr)
        return 1
    except FileNotFoundError as error:
        print(f"vertebra {args.command}: error: {error.filename}: file not found", file=sys.stderr)
        return 2
    except OSError as error:            # a disk fault outside the catalogue (plots, meshes, exports)
        where = f"{error.filename}: " if error.filename else ""
        print(f"vertebra {args.command}: error: {where}{error.strerror or error}", file=sys.stderr)
        return 2
    except MemoryError:                 # inputs are bounded where they are read; this is the last guard
        print(f"vertebra {args.command}: error: out of memory: the input asks for more than this machine has",
              file=sys.stderr)
        return 2

if __name__ == "__main__":
    sys.exit(main())
