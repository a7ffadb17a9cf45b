"""The JSON documents the command line prints on stdout (their fields: docs/json.md).

Every document carries ``"vertebra_version"``, the version of the vertebra that printed it: a
JSON object gets it as a field; a document that is a list (``catalogue ls``, ``catalogue
query``) gets it in each of its objects, so the list stays a list of entries.
"""

from __future__ import annotations

import json
import sys

from vertebra import __version__


def versioned(document):
    """``document`` with ``"vertebra_version"`` (first, in an object; in each object of a list)."""
    if isinstance(document, dict):
        return {"vertebra_version": __version__, **document}
    if isinstance(document, list):
        return [versioned(item) if isinstance(item, dict) else item for item in document]
    raise TypeError(f"a JSON document is an object or a list, got {type(document).__name__}")


def print_document(document, *, indent: int | None = None) -> None:
    """Print one JSON document (strict JSON: no NaN or infinity) and a newline on stdout."""
    json.dump(versioned(document), sys.stdout, allow_nan=False, indent=indent)
    sys.stdout.write("\n")
