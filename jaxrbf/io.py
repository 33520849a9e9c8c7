"""Reading and writing meshes, point clouds and 2-D polylines (host side: numpy and trimesh).

Every problem with a file or an array raises `jaxrbf.InputError` with a message that names the
file (or argument), says what is wrong and how to fix it. Writers are atomic: the output appears
only once it is complete, and an existing file is left untouched when writing fails.

- `.stl` `.off`: mesh (`write_mesh`).
- `.obj`: mesh; one with `v` lines but no faces is a point cloud for `read_input` (normals from
  its `vn` lines when there is one per vertex) (`write_mesh`).
- `.ply`: mesh if it has faces, else point cloud: x y z, optional nx ny nz (`write_mesh`,
  `write_points`).
- `.xyz` `.txt`: point cloud, one point per line: x y z first, then any further columns
  (colours, intensity, normals in any of the layouts scanners and CloudCompare write). Normals
  are the first triple of consecutive columns, at column offset 3, 4, 6 or 7 (0-based), whose
  columns each hold some negative values (colours, intensities and counts never do) and that
  has no row of zeros; the other columns are ignored (details: `read_points`). Whitespace,
  commas or semicolons separate the numbers; `#` starts a comment; one leading header line
  without numbers (`x,y,z`, `//X Y Z ...`) is skipped (`write_points`: `.xyz`, x y z
  [nx ny nz]).
- `.pts` (Leica PTS): point cloud; the first line is the point count, then x y z
  [intensity [r g b]] per line (never normals).
- `.npz`: `points` (+ `normals`): point cloud; `vertices` + `faces`: mesh (`write_points`,
  `write_mesh`; `write_polylines` writes `contour_0`, `contour_1`, ...).
- `.csv`: 3 or more columns: point cloud, read as `.xyz`; 2 columns (x, y): 2-D polyline
  (`write_polylines`: `.csv`, `contour,x,y`).
- `.npy`: 2-D polyline, an (n, 2) array.
"""

from __future__ import annotations

import math
import os
import re
import secrets
import warnings
import zipfile
import zlib
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._errors import InputError
from ._util import check_memory, check_scale, log, size_text

__all__ = [
    "Mesh",
    "PointCloud",
    "Polyline",
    "SUPPORTED",
    "MESH_OUTPUTS",
    "POINT_OUTPUTS",
    "POLYLINE_OUTPUTS",
    "as_points",
    "atomic_output",
    "check_output",
    "read_mesh",
    "read_points",
    "read_polyline",
    "read_input",
    "write_mesh",
    "write_points",
    "write_polylines",
]

SUPPORTED: dict[str, str] = {
    ".obj": "mesh or point cloud",
    ".ply": "mesh or point cloud",
    ".stl": "mesh",
    ".off": "mesh",
    ".xyz": "point cloud",
    ".txt": "point cloud",
    ".pts": "point cloud",
    ".npz": "point cloud or mesh",
    ".csv": "polyline or point cloud",
    ".npy": "polyline",
}
"""Input extensions and what they hold (used in error messages)."""

MESH_OUTPUTS = (".ply", ".obj", ".stl", ".off", ".npz")
POINT_OUTPUTS = (".ply", ".xyz", ".npz")
POLYLINE_OUTPUTS = (".csv", ".npz")
_MESH_INPUTS = (".obj", ".ply", ".stl", ".off", ".npz")
_POINT_INPUTS = (".ply", ".xyz", ".txt", ".pts", ".csv", ".npz")
_POLYLINE_INPUTS = (".csv", ".npy")


# --------------------------------------------------------------------------- containers


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh.

    **Arguments:**
    - `vertices`: (n, 3) float64 coordinates.
    - `faces`: (m, 3) int64 vertex indices (0-based).
    """

    vertices: np.ndarray
    faces: np.ndarray

    def __post_init__(self):
        v = np.asarray(self.vertices, dtype=np.float64)
        f = np.asarray(self.faces)
        if f.size == 0:
            f = f.reshape(0, 3)
        if v.ndim != 2 or v.shape[1] != 3:
            raise InputError(f"mesh vertices must have shape (n, 3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3:
            raise InputError(f"mesh faces must have shape (m, 3) (triangles), got {f.shape}")
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f.astype(np.int64, copy=False))


@dataclass(frozen=True, eq=False)
class PointCloud:
    """Points with optional normals.

    **Arguments:**
    - `points`: (n, d) float64, d = 2 or 3.
    - `normals`: (n, d) float64 or `None`.
    """

    points: np.ndarray
    normals: np.ndarray | None = None

    def __post_init__(self):
        p = np.asarray(self.points, dtype=np.float64)
        object.__setattr__(self, "points", p)
        if self.normals is not None:
            n = np.asarray(self.normals, dtype=np.float64)
            if n.shape != p.shape:
                raise InputError(
                    f"normals must have the same shape as the points {p.shape}, got {n.shape}"
                )
            object.__setattr__(self, "normals", n)


@dataclass(frozen=True, eq=False)
class Polyline:
    """A 2-D polyline.

    **Arguments:**
    - `vertices`: (n, 2) float64; a closed polyline does not repeat its first vertex at the end.
    - `closed`: whether the last vertex joins the first.
    """

    vertices: np.ndarray
    closed: bool

    def __post_init__(self):
        object.__setattr__(self, "vertices", np.asarray(self.vertices, dtype=np.float64))
        object.__setattr__(self, "closed", bool(self.closed))


# --------------------------------------------------------------------------- arrays


def as_points(array, name: str = "points", dims: tuple[int, ...] = (2, 3)) -> np.ndarray:
    """Validate an in-memory (n, d) array of coordinates.

    **Arguments:**
    - `array`: anything `np.asarray` turns into numbers.
    - `name`: the argument's name, used in messages.
    - `dims`: the allowed numbers of columns d.

    **Returns:** the array as C-contiguous float64 of shape (n, d).

    **Raises:** `InputError` when it is not numeric, not 2-D, has a wrong d, no rows, or holds
    NaN or infinite values.
    """
    if np.iscomplexobj(array):
        raise InputError(f"`{name}` holds complex numbers; coordinates must be real")
    try:
        a = np.asarray(array, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InputError(
            f"`{name}` must be an array of numbers of shape (n, d): {_short(e)}"
        ) from e
    if a.ndim != 2:
        raise InputError(
            f"`{name}` must be a 2-dimensional array of shape (n, d), got shape {a.shape}"
        )
    if a.shape[1] not in dims:
        raise InputError(
            f"`{name}` must have {_choices(dims)} columns (coordinates per point), "
            f"got shape {a.shape}"
        )
    if a.shape[0] == 0:
        raise InputError(f"`{name}` is empty: it holds no points (shape {a.shape})")
    bad = _count_nonfinite(a)
    if bad:
        raise InputError(
            f"`{name}` has {bad} row{'s' if bad != 1 else ''} with NaN or infinite values; "
            "remove or repair them"
        )
    check_scale(a, f"`{name}`")
    return np.ascontiguousarray(a)


def _as_faces(faces, n_vertices: int, name: str = "faces") -> np.ndarray:
    f = np.asarray(faces)
    if f.size == 0:
        raise InputError(f"`{name}` is empty: a mesh needs at least one triangle")
    if f.ndim != 2 or f.shape[1] != 3:
        raise InputError(f"`{name}` must have shape (m, 3) (triangles), got shape {f.shape}")
    if not np.issubdtype(f.dtype, np.integer):
        if not (np.issubdtype(f.dtype, np.floating) and np.all(f == np.round(f))):
            raise InputError(f"`{name}` must hold integer vertex indices, got dtype {f.dtype}")
    f = f.astype(np.int64)
    if f.min() < 0 or f.max() >= n_vertices:
        raise InputError(
            f"`{name}` refers to vertex indices from {f.min()} to {f.max()}, but there are "
            f"{n_vertices} vertices (indices are 0-based)"
        )
    return np.ascontiguousarray(f)


def _mesh_arrays(mesh_or_vertices, faces=None) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) from a Mesh, a trimesh, a (vertices, faces) pair or two arrays."""
    obj = mesh_or_vertices
    if faces is None:
        if hasattr(obj, "vertices") and hasattr(obj, "faces"):
            obj, faces = obj.vertices, obj.faces
        elif isinstance(obj, tuple) and len(obj) == 2:
            obj, faces = obj
        else:
            raise InputError(
                "give a Mesh, a (vertices, faces) pair, or vertices together with `faces`"
            )
    v = as_points(obj, "vertices", dims=(3,))
    return v, _as_faces(faces, len(v))


def _count_nonfinite(a: np.ndarray) -> int:
    return int(np.count_nonzero(~np.isfinite(a).all(axis=1)))


def _choices(items) -> str:
    items = [str(i) for i in items]
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " or " + items[-1]


def _short(e: BaseException, limit: int = 160) -> str:
    """The first line of an exception's message, without its class name (which means nothing
    to the user); a few words for an exception without a message."""
    text = str(e).strip()
    msg = text.splitlines()[0].rstrip(".") if text else "the data could not be decoded"
    return msg if len(msg) <= limit else msg[: limit - 3] + "..."


def _plural(n: int, word: str, plural: str | None = None) -> str:
    return f"{n:,} {word if n == 1 else (plural or word + 's')}"


def _items(n: int, element: str) -> str:
    """`n` items of the PLY element `element`, in words: '3 vertices', '1 triangle strip'."""
    words = {"vertex": ("vertex", "vertices"), "face": ("face", "faces")}
    words["tristrips"] = ("triangle strip", "triangle strips")
    word, plural = words.get(element, (f"'{element}' item", f"'{element}' items"))
    return _plural(n, word, plural)


# --------------------------------------------------------------------------- reading helpers


def _ext(path) -> str:
    return Path(path).suffix.lower()


def _unknown(path, ext: str, allowed) -> InputError:
    what = f"an unknown format '{ext}'" if ext else "no extension"
    return InputError(f"'{path}' has {what}; expected one of {', '.join(allowed)}")


def _check_file(path, allowed) -> tuple[str, str]:
    """The path as a string and its lower-case extension; InputError if unusable."""
    p = os.fspath(path)
    ext = _ext(p)
    if not os.path.exists(p):
        raise InputError(f"input file '{p}' does not exist; check the path")
    if os.path.isdir(p):
        raise InputError(f"input '{p}' is a folder, not a file")
    if ext not in allowed:
        if ext in SUPPORTED:
            raise InputError(
                f"'{p}' holds a {SUPPORTED[ext]} ({ext}), which cannot be read here; expected "
                f"one of {', '.join(allowed)} (read_input reads any supported file)"
            )
        raise _unknown(p, ext, allowed)
    if not os.access(p, os.R_OK):
        raise InputError(f"input file '{p}' cannot be read (permission denied)")
    if os.path.getsize(p) == 0:
        raise _empty(p)
    return p, ext


def _empty(p: str) -> InputError:
    return InputError(f"'{p}' is empty: it holds no vertices")


def _check_finite(p: str, a: np.ndarray) -> None:
    bad = _count_nonfinite(a)
    if bad:
        raise InputError(
            f"'{p}' has {bad} {'vertex' if bad == 1 else 'vertices'} with NaN or infinite "
            "coordinates; remove or repair them"
        )
    check_scale(a, f"'{p}'")


def _binary(p: str, head: bytes) -> bool:
    """Whether the first bytes of a file that should be text look like binary data."""
    return b"\0" in head


# --------------------------------------------------------------------------- PLY


#: Bytes of each PLY scalar type.
_PLY_TYPES = {
    "char": 1,
    "uchar": 1,
    "int8": 1,
    "uint8": 1,
    "short": 2,
    "ushort": 2,
    "int16": 2,
    "uint16": 2,
    "int": 4,
    "uint": 4,
    "int32": 4,
    "uint32": 4,
    "float": 4,
    "float32": 4,
    "double": 8,
    "float64": 8,
}
_PLY_FORMATS = ("ascii", "binary_little_endian", "binary_big_endian")
#: The PLY elements and properties jaxrbf reads; anything else is named on stderr.
_PLY_USED = {
    "vertex": ("x", "y", "z", "nx", "ny", "nz"),
    "face": ("vertex_indices", "vertex_index"),
    "tristrips": ("vertex_indices", "vertex_index"),
}


@dataclass(frozen=True)
class _PlyElement:
    name: str
    count: int
    #: (name, scalar type, list-length type or None) of each property.
    props: tuple[tuple[str, str, str | None], ...]


@dataclass(frozen=True)
class _PlyHeader:
    format: str
    elements: tuple[_PlyElement, ...]
    size: int  # bytes of the header

    def count(self, name: str) -> int:
        return sum(e.count for e in self.elements if e.name == name)


def _ply_header(p: str) -> _PlyHeader:
    """The PLY header of `p`, parsed and checked against the bytes that follow it (before any
    element is read, so that a header's claims are never allocated on trust)."""

    def bad(lineno: int, what: str) -> InputError:
        return InputError(f"'{p}' could not be read as PLY: header line {lineno}: {what}")

    fmt = None
    elements: list[tuple[str, int, list]] = []
    with open(p, "rb") as fh:
        if fh.readline(16).strip() != b"ply":
            raise InputError(f"'{p}' is not a PLY file: it does not start with 'ply'")
        for lineno in range(2, 100_002):
            line = fh.readline(4096)
            if not line:
                raise InputError(
                    f"'{p}' could not be read as PLY: its header never ends (no 'end_header' "
                    "line); the file is truncated"
                )
            words = line.decode("ascii", "replace").split()
            key = words[0] if words else ""
            if key == "end_header":
                break
            if key == "format":
                if len(words) < 2 or words[1] not in _PLY_FORMATS:
                    raise bad(lineno, f"unknown format {' '.join(words[1:])!r}")
                fmt = words[1]
            elif key == "element":
                if len(words) != 3 or not words[2].isdigit():
                    raise bad(lineno, f"expected 'element NAME COUNT', got {' '.join(words)!r}")
                elements.append((words[1], int(words[2]), []))
            elif key == "property":
                if not elements:
                    raise bad(lineno, "a property before any element")
                if len(words) == 5 and words[1] == "list":
                    if words[2] not in _PLY_TYPES or words[3] not in _PLY_TYPES:
                        raise bad(lineno, f"unknown list types {words[2]!r}, {words[3]!r}")
                    elements[-1][2].append((words[4], words[3], words[2]))
                elif len(words) == 3 and words[1] in _PLY_TYPES:
                    elements[-1][2].append((words[2], words[1], None))
                else:
                    raise bad(lineno, f"expected 'property TYPE NAME', got {' '.join(words)!r}")
        else:
            raise InputError(f"'{p}' could not be read as PLY: its header never ends")
        size = fh.tell()
    if fmt is None:
        raise InputError(f"'{p}' could not be read as PLY: its header has no 'format' line")
    header = _PlyHeader(fmt, tuple(_PlyElement(n, c, tuple(pr)) for n, c, pr in elements), size)
    _check_ply_sizes(p, header)
    return header


def _ply_counts(header: _PlyHeader) -> str:
    return ", ".join(_items(e.count, e.name) for e in header.elements)


def _check_ply_sizes(p: str, header: _PlyHeader) -> None:
    """Refuse a header whose element counts the bytes after it cannot hold (at least one byte
    and a separator per ASCII value, the exact size of each binary scalar and list length),
    or whose elements would not fit in memory."""
    present = os.path.getsize(p) - header.size
    need = 0
    memory = 0
    for e in header.elements:
        if header.format == "ascii":
            need += e.count * 2 * len(e.props)
        else:
            need += e.count * sum(_PLY_TYPES[lt or t] for _, t, lt in e.props)
        memory += e.count * sum(8 if lt is None else 8 * 4 for _, _, lt in e.props)
    if need > present:
        raise InputError(
            f"'{p}' could not be read as PLY: its header declares {_ply_counts(header)}, which "
            f"need at least {need:,} bytes, but only {present:,} follow it; the file is truncated"
        )
    check_memory(2 * memory, f"reading '{p}' ({_ply_counts(header)})", "use a smaller file")


def _ply_unused(p: str, header: _PlyHeader) -> None:
    """Name on stderr the elements and properties of `p` that jaxrbf does not use."""
    unused = []
    for e in header.elements:
        if e.name not in _PLY_USED:
            unused.append(f"element '{e.name}' ({_plural(e.count, 'item')})")
            continue
        extra = [name for name, _, _ in e.props if name not in _PLY_USED[e.name]]
        if extra:
            unused.append(f"{e.name} properties {', '.join(extra)}")
    if unused:
        log(f"'{p}': not used: {'; '.join(unused)}")


def _strip_triangles(strip: np.ndarray) -> np.ndarray:
    """The triangles of one PLY triangle strip (-1 restarts the strip; every other triangle's
    winding is reversed, so that all face the same way)."""
    out = []
    strip = np.asarray(strip, dtype=np.int64).reshape(-1)
    for run in np.split(strip, np.flatnonzero(strip < 0)):
        run = run[run >= 0]
        if len(run) < 3:
            continue
        tri = np.stack([run[:-2], run[1:-1], run[2:]], axis=1)
        tri[1::2] = tri[1::2, [1, 0, 2]]
        out.append(tri)
    return np.concatenate(out) if out else np.zeros((0, 3), dtype=np.int64)


def _ply_lists(data, key: str) -> list:
    """The lists of property `key` of a PLY element as trimesh reads them (ASCII: rows of a 2-D
    array or an object array of 1-D arrays; binary: (length, items) records); [] if absent."""
    a = data.get(key) if isinstance(data, dict) else None
    if a is None and data is not None and getattr(data, "dtype", None) is not None:
        a = data[key] if data.dtype.names and key in data.dtype.names else None
    if a is None:
        return []
    a = np.asarray(a) if not isinstance(a, np.ndarray) else a
    if a.dtype.names and len(a.dtype.names) == 2:  # binary: (list length, items)
        a = a[a.dtype.names[1]]
    return list(a)


def _ply_raw_length(element) -> int | None:
    """How many items of a raw trimesh PLY element were read (None: unknown)."""
    data = element.get("data")
    if isinstance(data, dict):
        lengths = [len(np.asarray(v)) for v in data.values()]
        return min(lengths) if lengths else 0
    if data is None:
        return 0
    return len(data) if hasattr(data, "__len__") else None


def _read_ply(p: str):
    """(vertices, faces or None, vertex properties) of a PLY file: faces from `face` (polygons
    fan-triangulated by trimesh) and from `tristrips`; every element's count checked."""
    import trimesh

    header = _ply_header(p)
    vertex = [e for e in header.elements if e.name == "vertex"]
    if not vertex or not {"x", "y", "z"} <= {n for n, _, _ in vertex[0].props}:
        raise InputError(
            f"'{p}' could not be read as PLY: it has no vertex element with x, y and z properties"
        )
    if header.count("vertex") == 0:
        raise _empty(p)
    try:
        g = _trimesh_load(p, ".ply")
    except InputError as e:
        if "unexpected length" in str(e):
            raise InputError(
                f"'{p}' could not be read as PLY: its data do not match its header "
                f"({_ply_counts(header)}): the file is truncated, has extra bytes at the end, "
                "or holds binary lists of varying length (mixed polygons or several triangle "
                "strips), which the PLY reader (trimesh) cannot read; save it as ASCII PLY"
            ) from e
        raise
    raw = {}
    for item in [g] + (list(g.geometry.values()) if isinstance(g, trimesh.Scene) else []):
        meta = getattr(item, "metadata", {}) or {}
        if isinstance(meta.get("_ply_raw"), dict):
            raw = meta["_ply_raw"]
            break
    for e in header.elements:
        got = _ply_raw_length(raw[e.name]) if isinstance(raw.get(e.name), dict) else None
        if got is not None and got != e.count:
            raise InputError(
                f"'{p}' could not be read as PLY: its header declares "
                f"{_items(e.count, e.name)} but the file holds {got:,}; it is truncated"
            )
    data = raw.get("vertex", {}).get("data")
    props: dict[str, np.ndarray] = {}
    if isinstance(data, dict):
        props = {k: np.asarray(v).reshape(-1) for k, v in data.items() if np.asarray(v).ndim <= 2}
    elif data is not None and getattr(data, "dtype", None) is not None and data.dtype.names:
        props = {k: np.asarray(data[k]).reshape(-1) for k in data.dtype.names}
    try:
        vertices = np.stack([props["x"], props["y"], props["z"]], axis=1).astype(np.float64)
    except (KeyError, ValueError) as e:
        raise InputError(
            f"'{p}' could not be read as PLY: its vertex coordinates are unreadable"
        ) from e
    faces = None
    if isinstance(g, trimesh.Trimesh) and len(g.faces):
        faces = np.asarray(g.faces, dtype=np.int64)
    elif isinstance(g, trimesh.Scene):
        meshes = [m for m in g.dump() if isinstance(m, trimesh.Trimesh) and len(m.faces)]
        if len(meshes) == 1 and len(meshes[0].vertices) == len(vertices):
            faces = np.asarray(meshes[0].faces, dtype=np.int64)
    strips = raw.get("tristrips", {}).get("data")
    if strips is not None:
        lists = _ply_lists(strips, "vertex_indices") or _ply_lists(strips, "vertex_index")
        tri = [_strip_triangles(s) for s in lists]
        tri = [t for t in tri if len(t)]
        if tri:
            faces = np.concatenate(([faces] if faces is not None else []) + tri)
    _ply_unused(p, header)
    return vertices, faces, props


# --------------------------------------------------------------------------- STL, OFF, OBJ


def _check_stl(p: str) -> bool:
    """Check an STL file's size against its header before it is read; True for binary STL."""
    size = os.path.getsize(p)
    with open(p, "rb") as fh:
        head = fh.read(84)
    if len(head) == 84:
        n = int.from_bytes(head[80:84], "little")
        if size == 84 + 50 * n:
            if n == 0:
                raise InputError(f"'{p}' holds no triangles (its binary STL header says 0)")
            return True
    else:
        n = None
    if head.lstrip()[:5].lower() == b"solid" and not _binary(p, head[:80]):
        return False  # ASCII STL: checked once read
    if n is None:
        raise InputError(
            f"'{p}' is not an STL file: it is too short ({size:,} bytes) for a binary STL "
            "(84-byte header) and does not start with 'solid' (ASCII STL)"
        )
    need = 84 + 50 * n
    if need > size:
        raise InputError(
            f"'{p}' could not be read as STL: its binary header declares "
            f"{_plural(n, 'triangle')}, which need {need:,} bytes, but the file has {size:,}; it "
            "is truncated"
        )
    raise InputError(
        f"'{p}' is not a valid binary STL file: its header declares {_plural(n, 'triangle')} "
        f"({need:,} bytes) but the file has {size:,} bytes"
    )


def _check_off(p: str) -> None:
    """Check an OFF file's header and its vertex and face lines (1-based line numbers) before
    trimesh reads it: the counts must be numbers, and the lines they announce must be there."""

    def bad(lineno: int, what: str) -> InputError:
        return InputError(f"'{p}' could not be read as OFF: line {lineno}: {what}")

    with open(p, "rb") as fh:
        head = fh.read(4096)
    if _binary(p, head):
        raise InputError(f"'{p}' is not a text OFF file: it holds binary data")
    with open(p, encoding="utf-8", errors="replace") as fh:
        lines = (
            (lineno, words)
            for lineno, line in enumerate(fh, 1)
            if (words := line.split("#", 1)[0].split())
        )  # the lines that hold data, streamed: a large file is never held as words
        lineno, words = next(lines, (0, [""]))
        if not words[0].upper().endswith("OFF"):
            raise InputError(f"'{p}' is not an OFF file: it does not start with 'OFF'")
        counts = words[1:]
        if not counts:
            lineno, counts = next(lines, (lineno, None))
            if counts is None:
                raise bad(lineno, "the header ends before the vertex and face counts")
        if len(counts) < 2 or not all(w.isdigit() for w in counts[:3]):
            raise bad(
                lineno, f"expected the counts 'vertices faces edges', got {' '.join(counts)!r}"
            )
        nv, nf = int(counts[0]), int(counts[1])
        if nv == 0:
            raise _empty(p)
        header, seen = lineno, 0
        for lineno, words in lines:
            if seen < nv and len(words) < 3:
                raise bad(lineno, f"a vertex needs 3 coordinates, got {' '.join(words)!r}")
            if nv <= seen < nv + nf:
                k = int(words[0]) if words[0].isdigit() else -1
                if k < 3 or len(words) < k + 1:
                    got = " ".join(words)
                    raise bad(
                        lineno, f"expected 'k i1 ... ik' (k >= 3 vertex indices), got {got!r}"
                    )
            seen += 1
            if seen == nv + nf:
                return
    raise InputError(
        f"'{p}' could not be read as OFF: its header (line {header}) declares "
        f"{_plural(nv, 'vertex', 'vertices')} and {_plural(nf, 'face')}, but only "
        f"{_plural(seen, 'line')} of data follow; the file is truncated"
    )


def _trimesh_load(p: str, ext: str):
    import trimesh

    try:
        with open(p, "rb") as fh, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return trimesh.load(fh, file_type=ext[1:], process=False)
    except InputError:
        raise
    except Exception as e:  # trimesh raises many kinds on corrupt input
        raise InputError(
            f"'{p}' could not be read as {ext[1:].upper()}: {_short(e)}; check that the file is "
            "complete and in that format"
        ) from e


def _read_obj(p: str, vn: list | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Vertices (the `v` lines, in order) and fan-triangulated faces of a Wavefront OBJ; the
    words of its `vn` lines are appended to `vn` when given (see `_obj_normals`).

    Parsed here rather than by trimesh, which splits vertices along texture seams and drops
    unreferenced ones.
    """
    with open(p, "rb") as fh:
        if _binary(p, fh.read(4096)):
            raise InputError(f"'{p}' is not a text OBJ file: it holds binary data")
    verts: list[list[str]] = []
    faces: list[list[int]] = []
    lineno = 0
    try:
        with open(p, encoding="utf-8", errors="replace") as fh:
            for lineno, line in enumerate(fh, 1):  # noqa: B007 (used in the message)
                if line.startswith(("v ", "v\t")):
                    w = line.split()
                    if len(w) < 4:
                        raise ValueError("a `v` line needs 3 coordinates")
                    verts.append(w[1:4])
                elif vn is not None and line.startswith(("vn ", "vn\t")):
                    vn.append(line.split()[1:4])
                elif line.startswith(("f ", "f\t")):
                    try:
                        idx = [int(w.split("/", 1)[0]) for w in line.split()[1:]]
                    except ValueError:
                        raise ValueError("a face's vertex indices must be whole numbers") from None
                    if len(idx) < 3 or 0 in idx:
                        raise ValueError("a face needs at least 3 vertex indices, counted from 1")
                    n = len(verts)
                    idx = [i - 1 if i > 0 else n + i for i in idx]
                    faces.extend([idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1))
        lineno = 0
        v = np.array(verts, dtype=np.float64).reshape(-1, 3)
    except (ValueError, UnicodeError) as e:
        if lineno:
            why = f"line {lineno}: {_short(e)}"
        else:  # a coordinate that is not a number: find its line
            why = f"line {_first_bad_obj_line(p, 'v')}: a vertex coordinate is not a number"
        raise InputError(
            f"'{p}' could not be read as OBJ: {why}; check that the file is complete and in "
            "that format"
        ) from e
    if len(v) == 0:
        if not _has_data_lines(p):
            raise _empty(p)
        raise InputError(
            f"'{p}' holds no vertices ('v x y z' lines): it is truncated or not an OBJ file"
        )
    return v, (np.array(faces, dtype=np.int64) if faces else None)


def _has_data_lines(p: str) -> bool:
    """Whether a text file holds anything but blank lines and `#` comments."""
    with open(p, encoding="utf-8", errors="replace") as fh:
        return any(line.split("#", 1)[0].strip() for line in fh)


def _first_bad_obj_line(p: str, key: str) -> int:
    """The first `key` line (`v`, `vn`) of an OBJ without 3 numbers (1-based; 0: none)."""
    with open(p, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            if line.startswith((key + " ", key + "\t")):
                try:
                    if len([float(w) for w in line.split()[1:4]]) < 3:
                        return lineno
                except ValueError:
                    return lineno
    return 0


def _obj_normals(p: str, words: list[list[str]], n: int) -> np.ndarray | None:
    """The normals of an OBJ point cloud of `n` vertices from the words of its `vn` lines: one
    per vertex, in order, else none."""
    if len(words) != n:
        return None
    try:
        if any(len(w) != 3 for w in words):
            raise ValueError
        return np.array(words, dtype=np.float64)
    except ValueError as e:
        raise InputError(
            f"'{p}' could not be read as OBJ: line {_first_bad_obj_line(p, 'vn')}: a normal "
            "('vn nx ny nz') needs 3 numbers"
        ) from e


def _load_geometry(p: str, ext: str):
    """(vertices, faces or None, ply vertex properties or {}) of a PLY, STL or OFF file."""
    import trimesh

    if ext == ".ply":
        return _read_ply(p)
    binary = False
    if ext == ".stl":
        binary = _check_stl(p)
    elif ext == ".off":
        _check_off(p)
    g = _trimesh_load(p, ext)
    if isinstance(g, trimesh.Scene):
        meshes = [m for m in g.dump() if isinstance(m, trimesh.Trimesh)]
        if meshes:
            g = trimesh.util.concatenate(meshes) if len(meshes) > 1 else meshes[0]
        else:
            clouds = [m for m in g.dump() if isinstance(m, trimesh.PointCloud)]
            if not clouds:
                if ext == ".stl" and not binary:
                    raise InputError(
                        f"'{p}' holds no complete ASCII STL facet ('facet normal ... "
                        "endfacet'): it is truncated or not an STL file"
                    )
                raise _empty(p)
            g = clouds[0]
    vertices = np.asarray(g.vertices, dtype=np.float64).reshape(-1, 3)
    faces = getattr(g, "faces", None)
    faces = None if faces is None or len(faces) == 0 else np.asarray(faces, dtype=np.int64)
    return vertices, faces, {}


# --------------------------------------------------------------------------- .npy and .npz


def _npy_header(fh, what: str) -> tuple[tuple[int, ...], np.dtype]:
    """(shape, dtype) from the header of the .npy stream `fh` (left after the header)."""
    try:
        magic = fh.read(8)
        if len(magic) < 8 or magic[:6] != b"\x93NUMPY":
            raise ValueError("it does not start with the .npy signature")
        version = (magic[6], magic[7])
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
        elif version in ((2, 0), (3, 0)):
            shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
        else:
            raise ValueError(
                f"it is in .npy format version {version[0]}.{version[1]}, unknown here"
            )
    except (ValueError, EOFError, OSError, SyntaxError) as e:
        raise InputError(f"{what} is not a .npy array: {_short(e)}") from e
    if dtype.hasobject:
        raise InputError(
            f"{what} holds Python objects, not numbers; jaxrbf reads only plain numeric arrays"
        )
    return tuple(int(s) for s in shape), dtype


def _check_npy_size(what: str, shape, dtype, present: int) -> None:
    """Refuse an array header that claims more bytes than follow it or than memory holds."""
    count = math.prod(shape)
    nbytes = count * dtype.itemsize
    if nbytes > present:
        raise InputError(
            f"{what} declares an array of shape {shape} ({size_text(nbytes)}) but holds only "
            f"{size_text(present)} of data: it is truncated or corrupt"
        )
    check_memory(nbytes + 8 * count, f"reading {what} (shape {shape})", "use a smaller file")


def _read_npy(p: str) -> np.ndarray:
    """The array of the .npy file `p`, its header checked before the data are read."""
    with open(p, "rb") as fh:
        if fh.read(6) != b"\x93NUMPY":
            what = "a zip archive (.npz?)" if is_zip_file(p) else "another kind of file"
            raise InputError(f"'{p}' is not a .npy array: it is {what}")
        fh.seek(0)
        shape, dtype = _npy_header(fh, f"'{p}'")
        _check_npy_size(f"'{p}'", shape, dtype, os.path.getsize(p) - fh.tell())
        fh.seek(0)
        try:
            return np.lib.format.read_array(fh, allow_pickle=False)
        except (ValueError, OSError, EOFError) as e:
            raise InputError(f"'{p}' could not be read as a .npy array: {_short(e)}") from e


def is_zip_file(path) -> bool:
    """Whether the file at `path` starts like a zip archive (an .npz is one)."""
    with open(path, "rb") as fh:
        return fh.read(4) in (b"PK\x03\x04", b"PK\x05\x06")


#: Deflate expands at most about 1032 times; a member that claims more is refused unread.
_MAX_DEFLATE_RATIO = 1100


def read_npz(p: str, hint: str = "") -> dict[str, np.ndarray]:
    """Every array of the .npz archive `p`, read with `allow_pickle=False`.

    Every member's header is checked before its data are read: its shape against the bytes the
    archive holds for it and against the memory available. Any failure (missing, truncated or
    corrupt archive, a member that is not a numeric .npy array, a file that is no zip archive
    at all) is an `InputError` naming the file; `hint` is appended to its message."""
    with open(p, "rb") as fh:
        head = fh.read(6)
    if head == b"\x93NUMPY":
        raise InputError(f"'{p}' is a single .npy array, not an .npz archive of named arrays{hint}")
    if not is_zip_file(p):
        kind = "binary data" if _binary(p, head) else "text"
        raise InputError(
            f"'{p}' is not an .npz archive (a zip of .npy arrays): it holds {kind}{hint}"
        )
    out: dict[str, np.ndarray] = {}
    total = 0
    try:
        with zipfile.ZipFile(p) as zf:
            for info in zf.infolist():
                name = info.filename
                if info.is_dir():
                    continue
                if not name.endswith(".npy"):
                    raise InputError(
                        f"'{p}' could not be read as an .npz archive: member '{name}' is not a "
                        f".npy array{hint}"
                    )
                what = f"'{p}' could not be read as an .npz archive: array '{name[:-4]}'"
                limit = info.compress_size * (
                    1 if info.compress_type == zipfile.ZIP_STORED else _MAX_DEFLATE_RATIO
                )
                with zf.open(info) as fh:
                    shape, dtype = _npy_header(fh, what)
                    present = min(info.file_size, limit + 1024) - fh.tell()
                _check_npy_size(what, shape, dtype, present)
                total += math.prod(shape) * (dtype.itemsize + 8)
                check_memory(total, f"reading '{p}'", "use a smaller file")
                with zf.open(info) as fh:
                    out[name[:-4]] = np.lib.format.read_array(fh, allow_pickle=False)
    except InputError as e:
        if hint and not str(e).endswith(hint):
            raise InputError(f"{e}{hint}") from e
        raise
    except (
        zipfile.BadZipFile,
        ValueError,
        OSError,
        EOFError,
        RuntimeError,
        NotImplementedError,
        zlib.error,
    ) as e:
        raise InputError(
            f"'{p}' could not be read as an .npz archive (truncated or corrupt: {_short(e)}){hint}"
        ) from e
    return out


# --------------------------------------------------------------------------- text tables


def _loadtxt(p: str, what: str, **kw) -> np.ndarray:
    with open(p, "rb") as fh:
        if _binary(p, fh.read(4096)):
            raise InputError(f"'{p}' could not be read as {what}: it holds binary data, not text")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data"
            return np.loadtxt(p, dtype=np.float64, ndmin=2, **kw)
    except (ValueError, OSError) as e:
        raise InputError(
            f"'{p}' could not be read as {what}: {_bad_line(p, kw.get('delimiter'), kw.get('skiprows', 0))}"
        ) from e


def _bad_line(p: str, delimiter: str | None, skip: int) -> str:
    """Where and why a text table fails to load: the first line (1-based) that holds something
    other than numbers, or whose count of numbers differs from the first data line's."""
    width = None
    with open(p, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            if lineno <= skip:
                continue
            words = [w.strip() for w in line.split("#", 1)[0].split(delimiter)]
            if delimiter is None:
                words = [w for w in words if w]
            if not any(words):
                continue
            for w in words:
                try:
                    float(w)
                except ValueError:
                    return f"line {lineno}: {w[:40]!r} is not a number"
            if width is None:
                width = len(words)
            elif len(words) != width:
                return (
                    f"line {lineno} holds {len(words)} numbers but the first data line holds "
                    f"{width}; every line must hold the same number of numbers"
                )
    return "every line must hold the same number of numbers"


#: What separates the words of a line when looking for a header or a point count.
_SEPARATORS = re.compile(r"[\s,;]+")
#: Header names of normal columns (lower case), as CloudCompare, PCL and Open3D write them.
_NORMAL_NAMES = (("nx", "ny", "nz"), ("normal_x", "normal_y", "normal_z"))
#: Where a point list's normals may start (0-based columns): x y z nx ny nz ..., x y z i nx ny nz,
#: x y z r g b nx ny nz, x y z i r g b nx ny nz.
_NORMAL_OFFSETS = (3, 4, 6, 7)


@dataclass(frozen=True)
class _TextLayout:
    """The start of a text point list."""

    skip: int  # lines before the data (comments, a header, a .pts count), for np.loadtxt
    delimiter: str | None  # what separates the numbers; None: whitespace
    header: tuple[str, ...] | None  # the header's words, lower case
    width: int | None  # numbers on the first data line; None: no data
    count: tuple[int, int] | None  # a .pts file's point count and its line


def _is_number(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def _text_layout(p: str, what: str, count_line: bool = False) -> _TextLayout:
    """Read the first lines of a text point list: one leading line without any number is a
    header (`x,y,z`, `//X Y Z`), a leading single whole number is the point count (`count_line`: .pts),
    and the first data line says what separates the numbers (a semicolon, else a comma, else
    whitespace). Blank lines and `#` comments are passed over."""
    with open(p, "rb") as fh:
        if _binary(p, fh.read(4096)):
            raise InputError(f"'{p}' could not be read as {what}: it holds binary data, not text")
    skip, header, count = 0, None, None
    with open(p, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            text = line.split("#", 1)[0].strip()
            if not text:
                continue
            words = [w for w in _SEPARATORS.split(text) if w]
            if not skip and not any(_is_number(w) for w in words):
                skip, header = (
                    lineno,
                    tuple(w.lower() for w in _SEPARATORS.split(text.lstrip("/")) if w),
                )
                continue
            if not skip and count_line and len(words) == 1 and words[0].isdigit():
                skip, count = lineno, (int(words[0]), lineno)
                continue
            delimiter = ";" if ";" in text else "," if "," in text else None
            return _TextLayout(skip, delimiter, header, len(text.split(delimiter)), count)
    return _TextLayout(skip, None, header, None, count)


def _normal_columns(data: np.ndarray, header: tuple[str, ...] | None) -> int | None:
    """The first column of a point list's normals (see `read_points`), or None.

    Columns a header names nx ny nz (or normal_x ...) are the normals. Otherwise a triple of
    consecutive columns at `_NORMAL_OFFSETS` looks like normals when each of its columns holds
    some negative values (colours, intensities and counts never do), or when some column does
    and every row has unit length (normals facing one half-space, e.g. a terrain's). Of those,
    the first is taken, with two preferences: one whose (nonzero) rows have unit length goes
    before one whose rows do not, so that a triple straddling two groups of signed columns
    (a signed scalar then nx ny nz, or nx ny nz with a row of zeros then a signed scalar) is
    not taken for the normals; then one without a row of zeros before one with (taken only so
    that such rows are refused as zero-length normals, rather than all the normals dropped
    unsaid). Rows with NaN or infinity are refused later, not weighed here."""
    width = data.shape[1]
    if header is not None and len(header) == width:
        for names in _NORMAL_NAMES:
            for k in range(3, width - 2):
                if header[k : k + 3] == names:
                    return k
    best, best_rank = None, None
    for k in _NORMAL_OFFSETS:
        if k + 3 > width:
            break
        t = data[:, k : k + 3]
        signed = (t < 0).any(axis=0)
        zero = ~(t != 0).any(axis=1)
        length = np.linalg.norm(t[~zero & np.isfinite(t).all(axis=1)], axis=1)
        unit = bool(len(length)) and bool(np.all(np.abs(length - 1) <= 1e-2))
        if not (signed.all() or (signed.any() and unit)):
            continue
        rank = (not unit, bool(zero.any()))
        if best_rank is None or rank < best_rank:
            best, best_rank = k, rank
    return best


def _read_point_list(p: str, ext: str) -> tuple[np.ndarray, np.ndarray | None]:
    """(points, normals or None) of a text point list (`.xyz` `.txt` `.pts` `.csv`)."""
    what = "a point list (x y z [more columns] per line)"
    layout = _text_layout(p, what, count_line=ext == ".pts")
    h = layout.header
    if h is not None and len(h) == layout.width and "x" in h and h[0] != "x":
        hint = ""
        if h == ("contour", "x", "y"):
            hint = " (this is a 2-D curve file: read it with read_polyline or read_input)"
        raise InputError(
            f"'{p}' names its columns '{' '.join(h)}' on its first line; a point list must "
            f"start with the columns x y z{hint}"
        )
    data = _loadtxt(p, what, delimiter=layout.delimiter, skiprows=layout.skip)
    rows = len(data) if data.size else 0
    if layout.count is not None and layout.count[0] != rows and (rows or layout.count[0]):
        count, line = layout.count
        raise InputError(
            f"'{p}' declares {_plural(count, 'point')} on line {line}, but {_plural(rows, 'row')} "
            "of numbers follow; the file is truncated or its count is wrong"
        )
    if rows == 0:
        raise _empty(p)
    width = data.shape[1]
    if width < 3:
        hint = ""
        if ext == ".csv" and width == 2:
            hint = "; a 2-column .csv is a 2-D polyline: read it with read_polyline or read_input"
        raise InputError(
            f"'{p}' has {_plural(width, 'column')}; a point list needs at least 3 (x y z first, "
            f"then any other columns){hint}"
        )
    k = None if ext == ".pts" else _normal_columns(data, h)
    return data[:, :3], None if k is None else data[:, k : k + 3]


# --------------------------------------------------------------------------- readers


def read_mesh(path) -> Mesh:
    """Read a triangle mesh (`.obj`, `.ply`, `.stl`, `.off`, or `.npz` with `vertices`, `faces`).

    Vertices are kept as the file lists them (none merged, split, reordered or dropped, even
    unreferenced ones); polygons are split into triangles. The exception is `.stl`, which stores
    every triangle's corners separately: there, exactly coincident corners are joined so that the
    mesh is connected.

    **Arguments:**
    - `path`: the file.

    **Returns:** a `Mesh`.

    **Raises:** `InputError` for a missing, empty, corrupt or unknown file, a file without
    faces, NaN or infinite coordinates, or out-of-range face indices.
    """
    p, ext = _check_file(path, _MESH_INPUTS)
    if ext == ".npz":
        return _npz_mesh(p, read_npz(p))
    if ext == ".obj":
        vertices, faces = _read_obj(p)
    else:
        vertices, faces, _ = _load_geometry(p, ext)
    return _mesh(p, ext, vertices, faces)


def _mesh(p: str, ext: str, vertices: np.ndarray, faces: np.ndarray | None) -> Mesh:
    """The checked `Mesh` of what a reader found in `p`."""
    if len(vertices) == 0:
        raise _empty(p)
    if faces is None:
        use = "read_input" if ext == ".obj" else "read_points or read_input"
        raise InputError(
            f"'{p}' has vertices but no faces; a mesh needs triangles (for a point cloud use "
            f"{use}, with normals)"
        )
    _check_finite(p, vertices)
    if ext == ".stl":
        vertices, inverse = np.unique(vertices, axis=0, return_inverse=True)
        faces = inverse.reshape(-1)[faces]
    return _validated_mesh(p, vertices, faces)


def _validated_mesh(p: str, vertices: np.ndarray, faces: np.ndarray) -> Mesh:
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    bad = np.count_nonzero(((faces < 0) | (faces >= len(vertices))).any(axis=1))
    if bad:
        raise InputError(
            f"'{p}' has {bad} face{'s' if bad != 1 else ''} referring to vertices it does not "
            f"hold (it has {len(vertices)} vertices); the file is corrupt or truncated"
        )
    return Mesh(np.ascontiguousarray(vertices, dtype=np.float64), faces)


def _real(p: str, name: str, a: np.ndarray) -> np.ndarray:
    """`a` if it holds real numbers (integers or floats), else an `InputError` naming `name`."""
    if a.dtype.kind not in "iuf":
        name = name if name.startswith("the ") else f"`{name}`"
        raise InputError(f"'{p}': {name} holds {a.dtype} values; expected real numbers")
    return a


def _npz_mesh(p: str, z: dict[str, np.ndarray]) -> Mesh:
    if "vertices" not in z or "faces" not in z:
        raise InputError(
            f"'{p}' has arrays {sorted(z)}; a mesh .npz needs `vertices` (n, 3) and `faces` (m, 3)"
        )
    v, f = _real(p, "vertices", z["vertices"]), _real(p, "faces", z["faces"])
    if v.ndim != 2 or v.shape[1] != 3 or not np.issubdtype(v.dtype, np.number):
        raise InputError(f"'{p}': `vertices` must have shape (n, 3), got {v.shape}")
    if len(v) == 0:
        raise _empty(p)
    v = v.astype(np.float64)
    _check_finite(p, v)
    if f.size == 0:
        raise InputError(f"'{p}' has vertices but no faces; a mesh needs triangles")
    return _validated_mesh(p, v, f)


def read_points(path) -> PointCloud:
    """Read a point cloud, with normals where the file has them.

    - `.ply`: vertex properties x, y, z and, if present, nx, ny, nz (faces are ignored).
    - `.xyz` / `.txt` / `.csv`: one point per line, x y z in the first three columns, then any
      number of other columns (`x y z r g b`, `x y z intensity`, `x y z nx ny nz`,
      `x y z r g b nx ny nz`, `x y z nx ny nz r g b`, `x y z i r g b`, ...). The normals are
      the first triple of consecutive columns, starting at column offset 3, 4, 6 or 7 (0-based)
      in that order, whose columns each hold some negative values (a surface's outward normals
      point every way; colours, intensities and counts are never negative) and that has no
      row of zeros; every other column is ignored. So `x y z r g b` (colours 0-255 or 0-1)
      gives points without normals, and `x y z nx ny nz` points with normals. Refinements: a
      triple with only some columns negative also counts if all its rows have unit length
      (normals facing one half-space, e.g. a terrain's); a triple of unit-length rows goes
      before one of other lengths (so that `x y z s nx ny nz`, s a signed scalar, gives
      nx ny nz); a triple that would be normals but for rows of zeros is taken when no other
      is, so that those rows are refused later as zero-length normals rather than all the
      normals dropped unsaid; columns a header names `nx ny nz` (or `normal_x normal_y
      normal_z`) are the normals. Numbers are separated by whitespace,
      commas or semicolons; `#` starts a comment; one leading header line without any number
      (`x,y,z`, `//X Y Z R G B`) is skipped; a header that puts x elsewhere than first is
      refused. A `.csv` needs 3 or more columns here (2 columns are a polyline:
      `read_polyline`).
    - `.pts` (Leica PTS): a first line with the point count, which must match the rows, then
      `x y z [intensity [r g b]]` per line; no normals.
    - `.npz`: `points` (n, 2 or 3) and optional `normals` of the same shape.

    **Arguments:**
    - `path`: the file.

    **Returns:** a `PointCloud` (`normals` is `None` when the file has none).

    **Raises:** `InputError` for a missing, empty, corrupt or unknown file, fewer than 3
    columns, rows of differing length or with words that are not numbers, wrong arrays, a
    `.pts` count that differs from its rows, or NaN or infinite values.
    """
    p, ext = _check_file(path, _POINT_INPUTS)
    normals = None
    if ext == ".ply":
        points, _, props = _load_geometry(p, ext)
        if all(k in props for k in ("nx", "ny", "nz")):
            normals = np.stack([props["nx"], props["ny"], props["nz"]], axis=1)
    elif ext == ".npz":
        z = read_npz(p)
        if "points" not in z:
            hint = " (it looks like a mesh: use read_mesh or read_input)" if "faces" in z else ""
            raise InputError(
                f"'{p}' has arrays {sorted(z)}; a point-cloud .npz needs `points` (n, d) and "
                f"optionally `normals` (n, d){hint}"
            )
        points = _real(p, "points", z["points"])
        normals = None if "normals" not in z else _real(p, "normals", z["normals"])
        if points.ndim != 2 or points.shape[1] not in (2, 3):
            raise InputError(
                f"'{p}': `points` must have shape (n, 2) or (n, 3), got {points.shape}"
            )
        if normals is not None and normals.shape != points.shape:
            raise InputError(
                f"'{p}': `normals` must have the shape of `points` {points.shape}, got "
                f"{normals.shape}"
            )
    else:
        points, normals = _read_point_list(p, ext)
    return _point_cloud(p, points, normals)


def _point_cloud(p: str, points, normals) -> PointCloud:
    """The checked `PointCloud` of what a reader found in `p`."""
    try:
        points = np.asarray(points, dtype=np.float64)
        normals = None if normals is None else np.asarray(normals, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InputError(f"'{p}' does not hold numeric coordinates: {_short(e)}") from e
    if len(points) == 0:
        raise _empty(p)
    _check_finite(p, points)
    if normals is not None:
        bad = _count_nonfinite(normals)
        if bad:
            raise InputError(
                f"'{p}' has {bad} normal{'s' if bad != 1 else ''} with NaN or infinite "
                "components; remove or repair them"
            )
    return PointCloud(
        np.ascontiguousarray(points),
        None if normals is None else np.ascontiguousarray(normals),
    )


def read_polyline(path, closed: bool | None = None) -> Polyline:
    """Read a 2-D polyline.

    - `.csv`: two comma-separated columns x, y, with an optional header line (e.g. `x,y`). A file
      written by `write_polylines` (`contour,x,y`) is read if it holds a single contour. A `.csv`
      of 3 or more columns is a point cloud: `read_points` or `read_input`.
    - `.npy`: an (n, 2) array.

    **Arguments:**
    - `path`: the file.
    - `closed`: whether the curve is closed; `None` (default): closed when the first vertex
      equals the last. The repeated last vertex of a closed curve is dropped.

    **Returns:** a `Polyline`.

    **Raises:** `InputError` for a missing, empty, corrupt or unknown file, other than two
    columns, fewer than 2 vertices (3 when closed), or NaN or infinite values.
    """
    p, ext = _check_file(path, _POLYLINE_INPUTS)
    if ext == ".npy":
        v = _real(p, "the array", _read_npy(p))
        if v.ndim != 2 or v.shape[1] != 2:
            raise InputError(f"'{p}' holds an array of shape {v.shape}; expected (n, 2) (x, y)")
        if not np.issubdtype(v.dtype, np.number):
            raise InputError(f"'{p}' holds {v.dtype} values; expected numbers")
    else:
        with open(p, encoding="utf-8", errors="replace") as fh:
            first = fh.readline()
        header = [w.strip().lower() for w in first.split(",")]
        skip = 0 if _numeric(header) else 1
        v = _loadtxt(p, "a CSV polyline (x,y per line)", delimiter=",", skiprows=skip)
        if v.size and v.shape[1] == 3 and header == ["contour", "x", "y"]:
            ids = np.unique(v[:, 0])
            if len(ids) != 1:
                raise InputError(
                    f"'{p}' holds {len(ids)} contours (column `contour`); read_polyline reads one "
                    "curve: split the file by contour"
                )
            v = v[:, 1:]
        if v.size == 0:
            raise _empty(p)
        if v.shape[1] != 2:
            hint = ""
            if v.shape[1] >= 3:
                hint = "; for a point cloud (x y z first) use read_points or read_input"
            raise InputError(
                f"'{p}' has {v.shape[1]} columns; a polyline needs exactly 2 (x, y){hint}"
            )
    v = np.asarray(v, dtype=np.float64)
    if len(v) == 0:
        raise _empty(p)
    _check_finite(p, v)
    repeated = len(v) > 1 and np.array_equal(v[0], v[-1])
    is_closed = repeated if closed is None else bool(closed)
    if is_closed and repeated:
        v = v[:-1]
    need = 3 if is_closed else 2
    if len(v) < need:
        raise InputError(
            f"'{p}' has {len(v)} distinct vertices; a{' closed' if is_closed else 'n open'} "
            f"polyline needs at least {need}"
        )
    return Polyline(np.ascontiguousarray(v), is_closed)


def _numeric(words: list[str]) -> bool:
    try:
        [float(w) for w in words if w]
    except ValueError:
        return False
    return True


def read_input(path) -> Mesh | PointCloud | Polyline:
    """Read any supported input, deciding its kind by extension and content.

    `.stl` `.off`: mesh; `.obj`: mesh, or point cloud if it has no faces (normals from its `vn`
    lines when there are as many as vertices); `.ply`: mesh if it has faces, else point cloud;
    `.xyz` `.txt` `.pts`: point cloud (`read_points`); `.npz`: mesh with `vertices` and `faces`,
    point cloud with `points`; `.csv`: point cloud with 3 or more columns, else polyline (also
    `contour,x,y` as `write_polylines` writes it); `.npy`: polyline (a polyline is closed if its
    first vertex equals its last).

    **Arguments:**
    - `path`: the file.

    **Returns:** a `Mesh`, `PointCloud` or `Polyline`.
    """
    p, ext = _check_file(path, tuple(SUPPORTED))
    if ext == ".obj":
        normals: list[list[str]] = []
        vertices, faces = _read_obj(p, normals)
        if faces is None:
            return _point_cloud(p, vertices, _obj_normals(p, normals, len(vertices)))
        return _mesh(p, ext, vertices, faces)
    if ext in (".stl", ".off"):
        return read_mesh(p)
    if ext == ".ply":
        header = _ply_header(p)
        has_faces = header.count("face") + header.count("tristrips") > 0
        return read_mesh(p) if has_faces else read_points(p)
    if ext in (".xyz", ".txt", ".pts"):
        return read_points(p)
    if ext == ".csv":
        layout = _text_layout(p, "a CSV table")
        if layout.header != ("contour", "x", "y") and (layout.width or 0) >= 3:
            return read_points(p)
    if ext == ".npz":
        z = read_npz(p)
        if "vertices" in z and "faces" in z:
            return _npz_mesh(p, z)
        if "points" in z:
            return read_points(p)
        if any(k.startswith("contour_") for k in z):
            raise InputError(
                f"'{p}' holds contours written by write_polylines; save one contour as .csv or "
                ".npy (n, 2) to read it as a polyline"
            )
        raise InputError(
            f"'{p}' has arrays {sorted(z)}; expected `points` (+ optional `normals`) for a point "
            "cloud, or `vertices` and `faces` for a mesh"
        )
    return read_polyline(p)


# --------------------------------------------------------------------------- writing


def _name_max(folder: str) -> int:
    try:
        return int(os.pathconf(folder, "PC_NAME_MAX"))
    except (OSError, ValueError, AttributeError):
        return 255


def check_output(path, allowed: tuple[str, ...] | None = None, what: str = "output") -> str:
    """Check, before any work starts, that `path` can be written: a known extension (one of
    `allowed`, when given), not a folder nor another non-file, in a folder that exists and is
    writable, with a name the file system accepts. Every failure is an `InputError` that names
    `path` as given (`what` says what it is, e.g. "output" or "--preview").

    **Returns:** the lower-case extension."""
    p = os.fspath(path)
    if not p:
        raise InputError(f"the {what} path is empty; give a file name")
    ext = _ext(p)
    if os.path.isdir(p):
        raise InputError(f"{what} '{p}' is a folder; give a file name inside it")
    if allowed is not None and ext not in allowed:
        got = f"an unsupported format '{ext}'" if ext else "no extension"
        raise InputError(f"{what} '{p}' has {got}; expected one of {', '.join(allowed)}")
    folder = os.path.dirname(os.path.abspath(p))
    if not os.path.isdir(folder):
        raise InputError(
            f"cannot write {what} '{p}': the folder '{folder}' does not exist; create it first"
        )
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputError(f"cannot write {what} '{p}': the folder '{folder}' is not writable")
    if os.path.lexists(p) and not os.path.isfile(p):
        raise InputError(f"cannot write {what} '{p}': it exists and is not a regular file")
    name = len(os.fsencode(os.path.basename(p)))
    limit = _name_max(folder)
    if name > limit:
        raise InputError(
            f"cannot write {what} '{p}': its file name is {name} bytes long, more than the file "
            f"system allows ({limit}); choose a shorter name"
        )
    return ext


@contextmanager
def atomic_output(path) -> Iterator[str]:
    """Write a file atomically.

    Yields a temporary path in the same folder, with the same suffix (so format detection by
    extension works). When the block succeeds, the temporary file replaces `path`; when it
    raises, the temporary file is deleted and an existing file at `path` is left as it was.

    **Arguments:**
    - `path`: the final output path; its folder must exist (see `check_output`).

    **Returns:** (yields) the temporary path to write to.
    """
    p = os.fspath(path)
    check_output(p)
    folder = os.path.dirname(os.path.abspath(p))
    base = os.path.basename(p)
    suffix = Path(base).suffix
    stem = base[: len(base) - len(suffix)] if suffix else base
    token = secrets.token_hex(4)
    tmp = f".{stem}.{token}.tmp{suffix}"
    if len(os.fsencode(tmp)) > _name_max(folder):  # a long name: a short temporary one
        tmp = f".jaxrbf-{token}.tmp{suffix}"
    tmp = os.path.join(folder, tmp)
    try:
        os.close(os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
    except OSError as e:
        raise InputError(f"cannot write '{p}': {e.strerror or _short(e)}") from e
    try:
        yield tmp
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, p)
    except OSError as e:
        with suppress(OSError):
            os.remove(tmp)
        if e.filename == tmp:  # name the user's path, not the temporary file's
            e.filename = p
        raise
    except BaseException:
        with suppress(OSError):
            os.remove(tmp)
        raise


def _out_ext(path, allowed, what: str) -> str:
    p = os.fspath(path)
    ext = _ext(p)
    if ext not in allowed:
        got = f"'{ext}'" if ext else "no extension"
        raise InputError(
            f"cannot write {what} to '{p}' ({got}); supported output formats: {', '.join(allowed)}"
        )
    return check_output(p, allowed)


def write_mesh(path, mesh_or_vertices, faces=None) -> None:
    """Write a triangle mesh atomically.

    `.ply` (binary, float64 vertices), `.obj` and `.off` (text, 17 significant digits) round-trip
    exactly; `.stl` stores float32 triangle corners; `.npz` holds `vertices` and `faces`.

    **Arguments:**
    - `path`: output file; the extension picks the format.
    - `mesh_or_vertices`: a `Mesh` (or anything with `vertices` and `faces`), a
      `(vertices, faces)` pair, or (n, 3) vertices together with `faces`.
    - `faces`: (m, 3) integer vertex indices when `mesh_or_vertices` is an array.

    **Returns:** `None`.
    """
    ext = _out_ext(path, MESH_OUTPUTS, "a mesh")
    v, f = _mesh_arrays(mesh_or_vertices, faces)
    with atomic_output(path) as tmp:
        if ext == ".ply":
            _write_ply(tmp, v, None, f)
        elif ext in (".obj", ".off"):
            _write_text_mesh(tmp, v, f, ext)
        elif ext == ".npz":
            with open(tmp, "wb") as fh:
                np.savez(fh, vertices=v, faces=f)
        else:
            import trimesh

            trimesh.Trimesh(v, f, process=False).export(tmp, file_type=ext[1:])


def _write_text_mesh(tmp: str, v: np.ndarray, f: np.ndarray, ext: str) -> None:
    with open(tmp, "w", encoding="ascii", newline="\n") as fh:
        if ext == ".obj":
            fh.write("# written by jaxrbf\n")
            np.savetxt(fh, v, fmt="v %.17g %.17g %.17g")
            np.savetxt(fh, f + 1, fmt="f %d %d %d")
        else:
            fh.write(f"OFF\n{len(v)} {len(f)} 0\n")
            np.savetxt(fh, v, fmt="%.17g %.17g %.17g")
            np.savetxt(fh, f, fmt="3 %d %d %d")


def _write_ply(tmp: str, v: np.ndarray, normals: np.ndarray | None, f: np.ndarray | None) -> None:
    """Binary little-endian PLY with float64 vertex properties (trimesh's exporter uses float32)."""
    names = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
    header = ["ply", "format binary_little_endian 1.0", "comment written by jaxrbf"]
    header.append(f"element vertex {len(v)}")
    header += [f"property double {n}" for n in names]
    if f is not None:
        header += [f"element face {len(f)}", "property list uchar int vertex_indices"]
    header.append("end_header")
    vert = np.empty(len(v), dtype=[(n, "<f8") for n in names])
    for i, n in enumerate(names[:3]):
        vert[n] = v[:, i]
    if normals is not None:
        for i, n in enumerate(names[3:]):
            vert[n] = normals[:, i]
    with open(tmp, "wb") as fh:
        fh.write(("\n".join(header) + "\n").encode("ascii"))
        fh.write(vert.tobytes())
        if f is not None:
            face = np.empty(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
            face["n"] = 3
            face["i"] = f
            fh.write(face.tobytes())


def write_points(path, points, normals=None) -> None:
    """Write points (and normals) atomically.

    **Arguments:**
    - `path`: `.ply` (binary, float64; 3-D only), `.xyz` (text x y z [nx ny nz]; 3-D only) or
      `.npz` (`points`, optional `normals`; 2-D or 3-D).
    - `points`: (n, d) coordinates.
    - `normals`: (n, d) normals or `None`.

    **Returns:** `None`.
    """
    ext = _out_ext(path, POINT_OUTPUTS, "points")
    dims = (2, 3) if ext == ".npz" else (3,)
    p = as_points(points, "points", dims=dims)
    n = None
    if normals is not None:
        n = as_points(normals, "normals", dims=dims)
        if n.shape != p.shape:
            raise InputError(f"`normals` must have the shape of `points` {p.shape}, got {n.shape}")
    with atomic_output(path) as tmp:
        if ext == ".ply":
            _write_ply(tmp, p, n, None)
        elif ext == ".xyz":
            data = p if n is None else np.hstack([p, n])
            np.savetxt(tmp, data, fmt="%.17g")
        else:
            arrays = {"points": p} if n is None else {"points": p, "normals": n}
            with open(tmp, "wb") as fh:
                np.savez(fh, **arrays)


def write_polylines(path, polylines: list[np.ndarray]) -> None:
    """Write 2-D curves atomically.

    **Arguments:**
    - `path`: `.csv` (header `contour,x,y`, one row per vertex, `contour` numbering the curves
      from 0) or `.npz` (arrays `contour_0`, `contour_1`, ... of shape (k, 2)).
    - `polylines`: a list of (k, 2) arrays (a single (k, 2) array is one curve). Curves are
      written as given: a closed curve keeps its repeated last vertex if it has one.

    **Returns:** `None`.
    """
    ext = _out_ext(path, POLYLINE_OUTPUTS, "polylines")
    if isinstance(polylines, np.ndarray) and polylines.ndim == 2:
        polylines = [polylines]
    curves = [as_points(c, f"polylines[{i}]", dims=(2,)) for i, c in enumerate(polylines)]
    save_curves(path, ext, curves, "contour", 2)


def save_curves(path, ext: str, curves: list[np.ndarray], label: str, dim: int) -> None:
    """Write checked (k, `dim`) `curves` atomically to `path`: `.csv` with header `label,x,y[,z]`
    (one row per vertex, `label` numbering the curves from 0) or `.npz` with arrays
    `label_0`, `label_1`, .... Shared by `write_polylines` (2-D) and
    `jaxrbf.features.write_feature_polylines` (3-D)."""
    with atomic_output(path) as tmp:
        if ext == ".csv":
            with open(tmp, "w", encoding="ascii", newline="\n") as fh:
                fh.write(",".join([label, *"xyz"[:dim]]) + "\n")
                for i, c in enumerate(curves):
                    ids = np.full((len(c), 1), i, dtype=np.float64)
                    np.savetxt(fh, np.hstack([ids, c]), fmt=["%d"] + ["%.17g"] * dim, delimiter=",")
        else:
            with open(tmp, "wb") as fh:
                np.savez(fh, **{f"{label}_{i}": c for i, c in enumerate(curves)})
