"""Reading the files a user names (scenes, sweep specs, trajectories) within stated limits.

Whatever a path points at — a text file in another encoding, a binary file, ``/dev/zero``, a
directory, a name with a NUL byte — the reader either returns the text or raises the
:class:`~vertebra.core.errors.InputError` kind the caller names, with one line that says why
and, for a limit, "at most N; got M". Nothing here allocates more than the limit it states:
a file is read in one bounded ``read`` of ``limit + 1`` bytes, and parsed TOML or JSON
documents are refused beyond a nesting depth of :data:`MAX_DEPTH` (deeper documents exhaust
the parsers' recursion: ``[[[[…]]]]`` is never a scene).
"""

from __future__ import annotations

from vertebra.core.errors import InputError

MAX_TEXT_BYTES = 16 * 2**20      # a scene, a sweep spec: 16 MiB (the largest gallery scene is 8 kB)
MAX_DEPTH = 32                   # tables and arrays nested in one document (a scene needs 4)


def _size(n: int) -> str:
    return f"{n / 2**20:.0f} MiB" if n >= 2**20 else f"{n} bytes"


def read_text(path, error: type[InputError] = InputError, *, limit: int = MAX_TEXT_BYTES) -> str:
    """The UTF-8 text of the file ``path``; ``error`` (an :class:`InputError` kind) names the
    file when it is missing, unreadable, not a regular file or FIFO, larger than ``limit``
    bytes, or not UTF-8 text."""
    name = str(path)
    if "\x00" in name:
        raise error("a file name cannot contain a NUL byte", file=name.replace("\x00", "\\x00"))
    try:
        with open(name, "rb") as handle:
            data = handle.read(limit + 1)
    except FileNotFoundError:
        raise error("file not found", file=name) from None
    except IsADirectoryError:
        raise error("is a directory, not a file", file=name) from None
    except OSError as failure:
        raise error(f"cannot read: {failure.strerror or failure}", file=name) from None
    if len(data) > limit:
        raise error(f"larger than the {_size(limit)} an input file may have (at most {limit} bytes; got more)",
                    file=name)
    if b"\x00" in data:
        at = data.index(b"\x00")
        raise error(f"a binary file, not text (a NUL byte at offset {at})", file=name)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as failure:
        line = data.count(b"\n", 0, failure.start) + 1
        raise error(f"not UTF-8 text: byte 0x{data[failure.start]:02x} on line {line} (save the file as UTF-8; "
                    "Latin-1 and Windows code pages are not read)", file=name) from None


def load_toml(path, error: type[InputError] = InputError, *, limit: int = MAX_TEXT_BYTES) -> dict:
    """The TOML document in the file ``path`` (read by :func:`read_text`), nested at most
    :data:`MAX_DEPTH` deep."""
    return parse_toml(read_text(path, error, limit=limit), error, source=str(path))


def parse_toml(text: str, error: type[InputError] = InputError, *, source: str = "<text>") -> dict:
    """``text`` as a TOML document; invalid TOML and nesting beyond :data:`MAX_DEPTH` raise ``error``."""
    import tomllib

    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as failure:
        raise error(f"not valid TOML: {failure}", file=source) from None
    except RecursionError:
        raise error(f"nested too deeply (at most {MAX_DEPTH} levels of tables and arrays)", file=source) from None
    check_depth(data, error, source=source)
    return data


def check_depth(document, error: type[InputError] = InputError, *, source: str = "<document>",
                limit: int = MAX_DEPTH) -> None:
    """Raise ``error`` when dictionaries and lists nest more than ``limit`` deep in ``document``
    (walked without recursion; the message names the path of the first too deep value)."""
    stack = [(document, "", 0)]
    while stack:
        value, where, depth = stack.pop()
        if isinstance(value, dict):
            items = value.items()
        elif isinstance(value, (list, tuple)):
            items = enumerate(value)
        else:
            continue
        if depth >= limit:
            raise error(f"nested too deeply (at most {limit} levels of tables and arrays; got more)", file=source,
                        field=where or None)
        for key, item in items:
            stack.append((item, f"{where}[{key}]" if isinstance(key, int) else (f"{where}.{key}" if where else str(key)),
                          depth + 1))


def parse_json(text: str, error: type[InputError] = InputError, *, source: str = "<json>", field=None):
    """``text`` as a JSON value nested at most :data:`MAX_DEPTH` deep (NaN and infinity refused)."""
    import json

    def refuse(constant):
        raise ValueError(f"{constant} is not a JSON number")

    try:
        value = json.loads(text, parse_constant=refuse)
    except RecursionError:
        raise error(f"nested too deeply (at most {MAX_DEPTH} levels)", file=source, field=field) from None
    except ValueError as failure:
        raise error(f"not valid JSON: {failure}", file=source, field=field) from None
    check_depth(value, error, source=source)
    return value


def count_limit(value: int, limit: int, error: type[InputError], *, what: str, file=None, field=None) -> int:
    """``value`` when ``0 < value <= limit``; otherwise ``error`` saying "at most N; got M"."""
    if value > limit:
        raise error(f"{what}: at most {limit:,}; got {value:,}", file=file, field=field)
    return value
