"""Defensive reading of HDF5 objects: every failure is a ``CatalogueError`` naming the file,
the object and the reason.

A catalogue may be damaged (bit flips, truncation) or crafted. These helpers are the only
way ``store`` touches objects inside a file, so every read path gets the same guards:

* **Hard links only.** A soft link (possibly a loop), an external link (into any file, e.g.
  ``/etc/passwd``) or a user-defined link is refused before it is followed.
* **No data outside the file.** Virtual datasets and datasets with external raw storage are
  refused: their bytes would come from other files.
* **Sizes before reading.** Attributes must be fixed-size: their stored size is known from
  their datatype and dataspace and is checked against a limit before anything is read.
  Variable-length attributes are refused unread (HDF5 only learns their length by reading
  them; vertebra never writes them). Dataset shapes are checked before allocation.
* **Bounded walks.** :func:`walk` visits every object of a file (or group) once, through hard
  links only, with a cap on the number of links, and reports what it refuses.

h5py raises ``KeyError``, ``OSError``, ``RuntimeError``, ``ValueError`` and others on damaged
files (the message is HDF5's last error, e.g. "bad object header version number"); all of
them become ``CatalogueError`` here.
"""

from __future__ import annotations

import os

import numpy as np

from vertebra.core.errors import CatalogueError

#: what h5py and the OS raise on a damaged file (HDF5's error stack mapped by h5py)
H5_ERRORS = (OSError, KeyError, ValueError, TypeError, RuntimeError, UnicodeError, IndexError,
             OverflowError, AttributeError, MemoryError, SystemError)

#: largest attribute vertebra reads (one canonical JSON dictionary), bytes
MAX_ATTRIBUTE_BYTES = 1 << 20
#: most links a walk visits in one file before giving up (a 10,000-entry catalogue has ~60,000)
MAX_LINKS = 10_000_000

_LINK_KINDS = {0: "hard link", 1: "soft link", 64: "external link"}


def failure(what: str, obj: str, reason) -> CatalogueError:
    """``CatalogueError("<file>: <object>: <reason>")`` on one line."""
    text = " ".join(str(reason).split()) or type(reason).__name__
    return CatalogueError(f"{what}: {obj}: {text}")


def _h5py():
    import h5py
    return h5py


def _join(path: str, name: str) -> str:
    return f"{path.rstrip('/')}/{name}"


def _low(obj):
    """The low-level h5py identifier of an h5py object (or the identifier itself)."""
    h5py = _h5py()
    return obj.id if isinstance(obj, (h5py.Group, h5py.Dataset)) else obj


def link_kind(group, name: str, what: str, path: str) -> str | None:
    """"hard link", "soft link", "external link", "user-defined link", or None if absent."""
    h5py = _h5py()
    gid = _low(group)
    try:
        if not gid.links.exists(name.encode()):
            return None
        kind = gid.links.get_info(name.encode()).type
    except H5_ERRORS as error:
        raise failure(what, _join(path, name), f"unreadable link ({error})") from None
    return "hard link" if kind == h5py.h5l.TYPE_HARD else _LINK_KINDS.get(kind, "user-defined link")


def check_dataset_storage(dataset, what: str, path: str) -> None:
    """Refuse datasets whose data live outside this file (virtual or external storage)."""
    h5py = _h5py()
    try:
        plist = _low(dataset).get_create_plist()
        layout = plist.get_layout()
        external = plist.get_external_count()
    except H5_ERRORS as error:
        raise failure(what, path, f"unreadable dataset layout ({error})") from None
    if layout == h5py.h5d.VIRTUAL:
        raise failure(what, path, "virtual dataset (its data would come from other files); refused")
    if external:
        raise failure(what, path, "dataset with external raw storage (its data would come from other "
                                  "files); refused")


def _open_child(group, name: str, what: str, path: str, kind: str, required: bool):
    """Low-level identifier of ``group/name`` (hard link, right kind, data in this file)."""
    h5py = _h5py()
    obj_path = _join(path, name)
    link = link_kind(group, name, what, path)
    if link is None:
        if required:
            raise failure(what, obj_path, f"{kind} missing")
        return None
    if link != "hard link":
        raise failure(what, obj_path, f"{link} refused: catalogue objects must be stored in the file itself "
                                      "(hard links only)")
    try:
        oid = h5py.h5o.open(_low(group), name.encode())
    except H5_ERRORS as error:
        raise failure(what, obj_path, f"unreadable object ({error})") from None
    expected = h5py.h5g.GroupID if kind == "group" else h5py.h5d.DatasetID
    if not isinstance(oid, expected):
        raise failure(what, obj_path, f"is not a {kind}")
    if kind == "dataset":
        check_dataset_storage(oid, what, obj_path)
    return oid


def child(group, name: str, what: str, path: str, kind: str, *, required: bool = True):
    """Open ``group/name`` through a hard link and check it is a ``kind`` ("group" or
    "dataset"; datasets must keep their data in this file). Returns an h5py Group or Dataset,
    or None when absent and not ``required``."""
    h5py = _h5py()
    oid = _open_child(group, name, what, path, kind, required)
    if oid is None:
        return None
    try:
        return h5py.Group(oid) if kind == "group" else h5py.Dataset(oid)
    except H5_ERRORS as error:
        raise failure(what, _join(path, name), f"unreadable object ({error})") from None


def member_names(group, what: str, path: str, limit: int = MAX_LINKS) -> list[str]:
    """Names of the links in ``group`` (no object is opened), at most ``limit``."""
    names: list[bytes] = []

    def collect(name):
        names.append(name)
        return 1 if len(names) > limit else None

    try:
        _low(group).links.iterate(collect)
    except H5_ERRORS as error:
        raise failure(what, path, f"unreadable group ({error})") from None
    if len(names) > limit:
        raise failure(what, path, f"more than {limit} members")
    out = []
    for raw in names:
        try:
            out.append(raw.decode("utf-8"))
        except UnicodeDecodeError:
            raise failure(what, path, f"member name {raw[:60]!r} is not UTF-8") from None
    return out


def _open_attribute(obj, name: str | bytes, what: str, path: str, limit: int):
    """Open an attribute after checking it is fixed-size and at most ``limit`` bytes."""
    h5py = _h5py()
    raw = name if isinstance(name, bytes) else name.encode()
    label = raw.decode("utf-8", "replace")
    oid = _low(obj)
    try:
        if not h5py.h5a.exists(oid, raw):
            raise failure(what, path, f"attribute {label!r} missing")
        attr = h5py.h5a.open(oid, raw)
        ftype = attr.get_type()
        variable = ftype.is_variable_str() if isinstance(ftype, h5py.h5t.TypeStringID) else \
            ftype.get_class() == h5py.h5t.VLEN
        size = int(attr.get_storage_size())
    except CatalogueError:
        raise
    except H5_ERRORS as error:
        raise failure(what, path, f"attribute {label!r} unreadable ({error})") from None
    if variable:
        raise failure(what, path, f"attribute {label!r} is variable-length (its size is unknown until it is "
                                  "read); vertebra stores fixed-length attributes only")
    if size > limit:
        raise failure(what, path, f"attribute {label!r} is {size} bytes > limit {limit}")
    return attr


def read_string_attribute(obj, name: str, what: str, path: str, limit: int = MAX_ATTRIBUTE_BYTES) -> str:
    """A scalar fixed-length UTF-8 string attribute, size-checked before reading."""
    attr = _open_attribute(obj, name, what, path, limit)
    try:
        dtype, shape = attr.dtype, attr.shape
        if shape != () or dtype.kind != "S":
            raise failure(what, path, f"attribute {name!r} is not a scalar string (dtype {dtype}, "
                                      f"shape {shape})")
        buf = np.empty((), dtype=dtype)
        attr.read(buf)
        raw = bytes(buf[()])
    except CatalogueError:
        raise
    except H5_ERRORS as error:
        raise failure(what, path, f"attribute {name!r} unreadable ({error})") from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        raise failure(what, path, f"attribute {name!r} is not UTF-8") from None


def read_number_attribute(obj, name: str, what: str, path: str, kinds: str = "f") -> float | int:
    """A scalar numeric attribute whose dtype kind is one of ``kinds`` ("f", "iu")."""
    attr = _open_attribute(obj, name, what, path, 64)
    try:
        dtype, shape = attr.dtype, attr.shape
        if shape != () or dtype.kind not in kinds:
            raise failure(what, path, f"attribute {name!r} is not a scalar of kind {kinds!r} "
                                      f"(dtype {dtype}, shape {shape})")
        buf = np.empty((), dtype=dtype)
        attr.read(buf)
    except CatalogueError:
        raise
    except H5_ERRORS as error:
        raise failure(what, path, f"attribute {name!r} unreadable ({error})") from None
    return buf[()].item()


def read_float_dataset(group, name: str, what: str, path: str, *, max_ndim: int = 2,
                       max_side: int = 4096) -> np.ndarray:
    """A float64 dataset (little- or big-endian) read as little-endian, shape-checked first."""
    h5py = _h5py()
    obj_path = _join(path, name)
    did = _open_child(group, name, what, path, "dataset", True)
    try:
        dtype, shape = did.dtype, did.shape
    except H5_ERRORS as error:
        raise failure(what, obj_path, f"unreadable dataset ({error})") from None
    if dtype not in (np.dtype("<f8"), np.dtype(">f8")):
        raise failure(what, obj_path, f"dtype {dtype}, expected float64")
    if shape is None or len(shape) > max_ndim or any(s > max_side for s in shape):
        raise failure(what, obj_path, f"shape {shape} (at most {max_ndim} dimensions of at most {max_side})")
    arr = np.empty(shape, dtype="<f8")
    if arr.size:
        try:
            did.read(h5py.h5s.ALL, h5py.h5s.ALL, arr)
        except H5_ERRORS as error:
            raise failure(what, obj_path, f"unreadable data ({error})") from None
    return arr


class _FileBytes:
    """Reads raw bytes of the file behind an open h5py object at HDF5 addresses (from the
    file on disk, or from the image of a file held in memory by the core driver)."""

    def __init__(self, obj, what: str, path: str):
        self.what, self.path = what, path
        self.image, self.fd = None, None
        try:
            fid = obj.file.id
            self.base = fid.get_create_plist().get_userblock()
            if obj.file.driver == "core":
                self.image = fid.get_file_image()
            else:
                name = obj.file.filename
        except H5_ERRORS as error:
            raise failure(what, path, f"unreadable file properties ({error})") from None
        if self.image is None:
            try:
                self.fd = os.open(name, os.O_RDONLY)
            except OSError as error:
                raise failure(what, path, f"cannot reopen the file ({error.strerror})") from None

    def close(self) -> None:
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None

    def read(self, offset: int, size: int) -> bytes:
        start = self.base + offset
        if self.image is not None:
            data = self.image[start:start + size]
        else:
            try:
                data = os.pread(self.fd, size, start) if size else b""
            except (OSError, OverflowError) as error:
                raise failure(self.what, self.path, f"cannot read bytes at {offset} ({error})") from None
        if len(data) != size:
            raise failure(self.what, self.path, f"refers to bytes {offset}…{offset + size} beyond the end of "
                                                "the file")
        return data


def _raw_elements(ds, reader, n: int, element: int, what: str, path: str) -> bytes:
    """The stored (unconverted) bytes of the first ``n`` elements of an unfiltered dataset."""
    h5py = _h5py()
    try:
        plist = ds.id.get_create_plist()
        layout, filters = plist.get_layout(), plist.get_nfilters()
    except H5_ERRORS as error:
        raise failure(what, path, f"unreadable dataset layout ({error})") from None
    if filters:
        raise failure(what, path, "filtered (compressed) variable-length data is not supported")
    if layout == h5py.h5d.CONTIGUOUS:
        try:
            offset = ds.id.get_offset()
        except H5_ERRORS as error:
            raise failure(what, path, f"unreadable dataset storage ({error})") from None
        if offset is None:
            raise failure(what, path, "rows declared but no storage allocated")
        return reader.read(offset, n * element)
    if layout != h5py.h5d.CHUNKED:
        raise failure(what, path, "storage layout not supported for variable-length rows (chunked or contiguous)")
    try:
        chunk = ds.chunks[0]
        infos = [ds.id.get_chunk_info(i) for i in range(ds.id.get_num_chunks())]
    except H5_ERRORS as error:
        raise failure(what, path, f"unreadable chunk index ({error})") from None
    by_start = {}
    for info in infos:
        if info.size != chunk * element or info.chunk_offset[0] % chunk:
            raise failure(what, path, f"chunk at row {info.chunk_offset[0]} has {info.size} bytes, expected "
                                      f"{chunk * element}")
        by_start[info.chunk_offset[0]] = info.byte_offset
    parts = []
    for start in range(0, n, chunk):
        if start not in by_start:
            raise failure(what, path, f"rows {start}… have no stored chunk")
        parts.append(reader.read(by_start[start], chunk * element))
    return b"".join(parts)[: n * element]


def _heap_objects(reader, address: int, sizeof_size: int, what: str, path: str) -> dict[int, int]:
    """Object index -> size of the global heap collection at ``address``, parsed and checked the
    way HDF5 reads it (a zeroed collection made HDF5 loop forever)."""
    header = reader.read(address, 8 + sizeof_size)
    if header[:4] != b"GCOL" or header[4] != 1:
        raise failure(what, path, f"global heap at address {address} has no valid signature (damaged file)")
    size = int.from_bytes(header[8:8 + sizeof_size], "little")
    if not len(header) <= size <= 1 << 30:
        raise failure(what, path, f"global heap at address {address} claims {size} bytes")
    heap = reader.read(address, size)
    objects, p, head = {}, len(header), 8 + sizeof_size
    while p < size:
        if p + head > size:                     # too small for an object header: free space
            break
        index = int.from_bytes(heap[p:p + 2], "little")
        length = int.from_bytes(heap[p + 8:p + 8 + sizeof_size], "little")
        need = length if index == 0 else head + (length + 7) // 8 * 8
        if need < head or p + need > size:
            raise failure(what, path, f"global heap at address {address}: object {index} of {length} bytes "
                                      "does not fit (damaged file)")
        if index:
            objects[index] = length
        p += need
    return objects


def read_string_rows(ds, what: str, path: str, *, max_rows: int, max_row_bytes: int) -> list[bytes]:
    """Rows of a 1-D variable-length string dataset, each row's length checked BEFORE anything
    is read: the heap references are read raw and every global heap collection they point
    into is parsed and checked first."""
    try:
        shape, dtype = ds.shape, ds.dtype
        vlen = _h5py().check_string_dtype(dtype)
        sizeof_addr, sizeof_size = ds.file.id.get_create_plist().get_sizes()
    except H5_ERRORS as error:
        raise failure(what, path, f"unreadable dataset ({error})") from None
    if shape is None or len(shape) != 1 or vlen is None or vlen.length is not None:
        raise failure(what, path, "is not a 1-D variable-length string dataset")
    n = shape[0]
    if n > max_rows:
        raise failure(what, path, f"{n} rows > limit {max_rows}")
    if n == 0:
        return []
    element = 4 + sizeof_addr + 4
    reader = _FileBytes(ds, what, path)
    try:
        raw = _raw_elements(ds, reader, n, element, what, path)
        # each stored element: uint32 length, heap collection address, uint32 object index
        refs = np.frombuffer(raw, dtype=np.dtype([("length", "<u4"), ("address", f"<u{sizeof_addr}"),
                                                  ("index", "<u4")]), count=n)
        too_long = np.flatnonzero(refs["length"] > max_row_bytes)
        if too_long.size:
            row = int(too_long[0])
            raise failure(what, f"{path} row {row}", f"{int(refs['length'][row])} bytes > limit {max_row_bytes}")
        heaps = {int(a): _heap_objects(reader, int(a), sizeof_size, what, path)
                 for a in np.unique(refs["address"][refs["length"] > 0])}
        for row, (length, address, index) in enumerate(refs.tolist()):
            if length and heaps[address].get(index, -1) < length:
                raise failure(what, f"{path} row {row}",
                              "refers to a missing or shorter global heap object (damaged file)")
    finally:
        reader.close()
    try:
        rows = ds[()]
    except H5_ERRORS as error:
        raise failure(what, path, f"unreadable rows ({error})") from None
    return [r if isinstance(r, bytes) else str(r).encode("utf-8") for r in rows]


def walk(root, what: str, path: str = "/", *, limit: int = MAX_LINKS,
         attribute_limit: int = MAX_ATTRIBUTE_BYTES, skip: frozenset = frozenset()) -> list[str]:
    """Every object under ``root`` through hard links, once: problems found (not raised).

    Refused: soft, external and user-defined links; virtual datasets and datasets with external
    storage; variable-length or oversized attributes; named datatypes; unreadable objects.
    Objects reachable through several hard links are visited once (so hard-link cycles end).
    The members of the groups whose paths are in ``skip`` are not visited (their callers walk
    them one by one).
    """
    h5py = _h5py()
    problems: list[str] = []
    seen: set = set()
    stack = [(_low(root), path)]
    visited = 0
    while stack:
        gid, gpath = stack.pop()
        _check_attributes(gid, what, gpath, attribute_limit, problems)
        if gpath in skip:
            continue
        try:
            names = member_names(gid, what, gpath, limit)
        except CatalogueError as error:
            problems.append(str(error))
            continue
        for name in names:
            visited += 1
            if visited > limit:
                problems.append(str(failure(what, gpath, f"more than {limit} objects; walk stopped")))
                return problems
            obj_path = _join(gpath, name)
            raw = name.encode()
            try:
                kind = link_kind(gid, name, what, gpath)
                if kind != "hard link":
                    raise failure(what, obj_path, f"{kind} refused: catalogue objects must be stored in the file "
                                                  "itself (hard links only)")
                info = h5py.h5o.get_info(gid, raw)
                token = (info.fileno, info.addr)
                if token in seen:
                    continue
                seen.add(token)
                if info.type == h5py.h5o.TYPE_GROUP:
                    stack.append((h5py.h5g.open(gid, raw), obj_path))
                elif info.type == h5py.h5o.TYPE_DATASET:
                    did = h5py.h5d.open(gid, raw)
                    check_dataset_storage(did, what, obj_path)
                    if info.num_attrs:
                        _check_attributes(did, what, obj_path, attribute_limit, problems)
                else:
                    raise failure(what, obj_path, "is neither a group nor a dataset")
            except CatalogueError as error:
                problems.append(str(error))
            except H5_ERRORS as error:
                problems.append(str(failure(what, obj_path, f"unreadable object ({error})")))
    return problems


def _check_attributes(oid, what: str, path: str, limit: int, problems: list) -> None:
    h5py = _h5py()
    names: list[bytes] = []
    try:
        h5py.h5a.iterate(oid, lambda name: names.append(name) if len(names) <= 1000 else 1)
    except H5_ERRORS as error:
        problems.append(str(failure(what, path, f"unreadable attributes ({error})")))
        return
    if len(names) > 1000:
        problems.append(str(failure(what, path, "more than 1000 attributes")))
        return
    for raw in names:
        try:
            _open_attribute(oid, raw, what, path, limit)
        except CatalogueError as error:
            problems.append(str(error))
