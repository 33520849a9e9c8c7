"""Host-side preparation: the normalising transform, duplicate merging, normals from meshes and
polylines. numpy and scipy only: this is the host end of the pipeline (see DESIGN.md)."""

from __future__ import annotations

import numpy as np

from ._errors import InputError
from ._util import check_memory

#: Host bytes per point `sample_faces` allocates (points, normals, triangles, barycentrics).
_SAMPLE_BYTES = 256


def bounding_box(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return points.min(axis=0), points.max(axis=0)


def diagonal(points: np.ndarray) -> float:
    lo, hi = bounding_box(np.asarray(points))
    return float(np.linalg.norm(hi - lo))


def unit_box_transform(points: np.ndarray, name: str = "points") -> tuple[np.ndarray, float]:
    """Shift and one uniform scale that map `points` into the box [-1/2, 1/2]^d.

    One scale for every axis (per-axis scaling would distort distances and so the RBF fit).

    **Returns:** `(shift, scale)`, with normalised = (x - shift) / scale.
    """
    lo, hi = bounding_box(points)
    scale = float(np.max(hi - lo))
    if not scale > 0:
        raise InputError(
            f"all {len(points)} `{name}` are the same point; a fit needs points that span some extent"
        )
    return (lo + hi) / 2.0, scale


def duplicate_pairs(points: np.ndarray, tol: float) -> np.ndarray:
    """(k, 2) index pairs i < j of points closer than `tol`."""
    from scipy.spatial import cKDTree

    pairs = cKDTree(points).query_pairs(r=tol, output_type="ndarray")
    return np.sort(pairs, axis=1) if len(pairs) else pairs.reshape(0, 2)


def linked_groups(
    points: np.ndarray, link: float, pairs: np.ndarray | None = None
) -> tuple[int, np.ndarray]:
    """The groups of `points` joined by chains of links shorter than `link`: their count and each
    point's group label (scipy's connected components of the k-d tree's pairs; `pairs`: those
    pairs, (k, 2), when already known)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = len(points)
    if pairs is None:
        pairs = cKDTree(points).query_pairs(link, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)


def find_duplicates(points: np.ndarray, tol: float, pairs: np.ndarray | None = None) -> np.ndarray:
    """Boolean mask of points that lie within `tol` of an earlier point (to drop)."""
    if pairs is None:
        pairs = duplicate_pairs(points, tol)
    drop = np.zeros(len(points), dtype=bool)
    drop[pairs[:, 1]] = True
    return drop


def auto_flag(value, name: str, auto: bool) -> bool:
    """A setting that takes "auto", True or False: `auto` for "auto", else its own truth value;
    anything else is an `InputError` naming `name`."""
    if isinstance(value, str) and value == "auto":
        return auto
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise InputError(f"`{name}` must be 'auto', True or False, got {value!r}")


def check_not_flat(points: np.ndarray, what: str = "points") -> None:
    """Raise when the points lie on one hyperplane (a plane in 3-D, a line in 2-D)."""
    n, d = points.shape
    shape = "plane" if d == 3 else "line"
    closed = "surface" if d == 3 else "curve"
    centred = points - points.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    if n <= d or s[0] == 0:
        many = "1 point" if n == 1 else f"{n} copies of one point" if s[0] == 0 else f"{n} points"
        raise InputError(
            f"the {what} are only {many}: a closed {closed} needs at least {d + 1} points that "
            f"do not all lie on one {shape}"
        )
    if s[-1] <= 1e-9 * s[0]:
        raise InputError(
            f"all {len(points)} {what} lie on one {shape}: they enclose no volume, so no closed "
            "surface can be reconstructed from them"
        )


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (sum of the unnormalised face normals around each vertex)."""
    tri = vertices[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    vn = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(vn, faces[:, k], fn)
    return vn


def sample_faces(
    vertices: np.ndarray, faces: np.ndarray, n: int, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """`n` points uniform over the mesh's area, each with its face's unit normal."""
    check_memory(_SAMPLE_BYTES * n, f"sampling {n:,} points on the mesh", "ask for fewer points")
    tri = vertices[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.linalg.norm(fn, axis=1)
    if not np.any(area > 0):
        raise InputError("every face of the mesh has zero area: there is no surface to sample")
    rng = np.random.default_rng(seed)
    idx = rng.choice(len(faces), size=n, p=area / area.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[idx]
    pts = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])
    return pts, fn[idx] / area[idx, None]


def polyline_normals(vertices: np.ndarray, closed: bool) -> np.ndarray:
    """Unit normals at the vertices of a 2-D polyline (mean of the adjacent segments' normals).

    A closed polyline's normals point out of the region it encloses, whichever way it winds. An open
    polyline has no inside: its normals point to the right of the walking direction.
    """
    v = np.asarray(vertices, dtype=float)
    seg = (np.roll(v, -1, axis=0) - v) if closed else np.diff(v, axis=0)
    length = np.linalg.norm(seg, axis=1)
    if np.any(length == 0):
        raise InputError("the polyline has repeated consecutive vertices (a zero-length segment)")
    sn = np.stack([seg[:, 1], -seg[:, 0]], axis=1) / length[:, None]
    if closed:
        signed_area = 0.5 * np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1])
        if signed_area < 0:
            sn = -sn
        vn = sn + np.roll(sn, 1, axis=0)
    else:
        vn = np.zeros_like(v)
        vn[:-1] += sn
        vn[1:] += sn
    norm = np.linalg.norm(vn, axis=1, keepdims=True)
    if np.any(norm == 0):
        raise InputError("the polyline folds back on itself (a vertex whose segments cancel)")
    return vn / norm


def consistent_winding(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, int]:
    """`faces` with every connected piece wound one way, and how many faces were turned.

    Meshes from modelling tools and converters often have faces wound against their neighbours
    (a polygon soup exported face by face, a piece mirrored in part): sampled with their face
    normals, such a face says "outside" where its neighbours say "inside". Vertices are joined
    where their coordinates are equal (a soup's faces repeat them); two faces that share an edge
    (and no third does) agree when they run along it in opposite directions. Each piece keeps
    the winding of the larger part of its area, so a piece wound inside out as a whole stays so
    (`jaxrbf._winding.inward_samples` turns such pieces out by the winding number). Faces that
    cannot agree with all neighbours (a Moebius strip) follow a spanning tree. Host, sorts and
    one breadth-first search: ~0.1 s per 100,000 faces (`trimesh.repair.fix_winding` takes
    ~10 s for 70,000 faces)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    f = np.asarray(faces, dtype=np.int64)
    m = len(f)
    if m < 2:
        return f, 0
    _, vid = np.unique(np.asarray(vertices, dtype=float), axis=0, return_inverse=True)
    fv = vid.reshape(-1)[f]
    e = fv[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    owner = np.repeat(np.arange(m), 3)
    lo, hi = np.minimum(e[:, 0], e[:, 1]), np.maximum(e[:, 0], e[:, 1])
    ok = lo != hi
    key = lo[ok] * (int(vid.max()) + 1) + hi[ok]
    fwd, owner = (e[ok, 0] < e[ok, 1]), owner[ok]
    order = np.argsort(key, kind="stable")
    key, fwd, owner = key[order], fwd[order], owner[order]
    start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    count = np.diff(np.r_[start, len(key)])
    pair = start[count == 2]
    a, b = owner[pair], owner[pair + 1]
    same = a != b
    a, b = a[same], b[same]
    flip = (fwd[pair] == fwd[pair + 1])[same]  # the same direction: one of the two is turned
    graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(m, m)).tocsr()
    n_pieces, label = connected_components(graph, directed=False)
    # one search from a virtual root joined to the first face of every piece
    roots = np.unique(label, return_index=True)[1]
    rows = np.r_[a, b, np.full(len(roots), m)]
    cols = np.r_[b, a, roots]
    tree = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(m + 1, m + 1)).tocsr()
    _, pred = breadth_first_order(tree, m, directed=True, return_predecessors=True)

    # the parity of each tree edge (parent -> face), looked up among the shared edges by the
    # pair's code (smaller face, larger face)
    def code(u, v):
        return np.minimum(u, v) * (m + 1) + np.maximum(u, v)

    codes, where = np.unique(code(a, b), return_index=True)
    parent = pred[:m].copy()
    parity = np.zeros(m + 1, dtype=bool)
    child = np.flatnonzero(parent != m)
    parity[child] = flip[where][np.searchsorted(codes, code(parent[child], child))]
    # each face's parity relative to its piece's root, by pointer doubling along the tree
    up = np.r_[parent, m]
    while np.any(up[:m] != m):
        parity[:m] ^= parity[up[:m]]
        up[:m] = up[up[:m]]
    area = 0.5 * np.linalg.norm(
        np.cross(vertices[f[:, 1]] - vertices[f[:, 0]], vertices[f[:, 2]] - vertices[f[:, 0]]),
        axis=1,
    )
    turned_area = np.bincount(label, weights=area * parity[:m], minlength=n_pieces)
    kept_area = np.bincount(label, weights=area * ~parity[:m], minlength=n_pieces)
    turn = parity[:m] ^ (turned_area > kept_area)[label]
    out = f.copy()
    out[turn] = out[turn][:, ::-1]
    return out, int(turn.sum())


def merged_duplicates(points: np.ndarray, normals: np.ndarray, tol: float):
    """Oriented samples with each group of points within `tol` of one another made one:
    `(points, normals, merged, dropped)`. A mesh's vertices exported with their normals repeat
    a vertex once per face along a crease or a seam, each copy with its own face's normal (the
    teapot's 393 seam vertices): where no two normals of a group face opposite ways (cosine
    below -1/2) the group keeps its first point with the mean of its normals (a crease's
    outward bisector); where two do, one place is said to face both ways (the edge of a sheet
    sampled on both faces) and the group is dropped, its neighbours standing for the surface
    there. `merged`, `dropped`: how many points were given up each way. `normals` unit."""
    pairs = duplicate_pairs(points, tol)
    if not len(pairs):
        return points, normals, 0, 0
    n = len(points)
    _, label = linked_groups(points, tol, pairs)
    size = np.bincount(label)
    opposed = np.einsum("ij,ij->i", normals[pairs[:, 0]], normals[pairs[:, 1]]) < -0.5
    bad = np.zeros(len(size), dtype=bool)
    bad[label[pairs[opposed, 0]]] = True
    total = np.stack([np.bincount(label, weights=normals[:, k]) for k in range(3)], axis=1)
    length = np.linalg.norm(total, axis=1)
    bad |= length < 1e-9 * size
    first = np.full(len(size), n)
    np.minimum.at(first, label, np.arange(n))
    keep = (np.arange(n) == first[label]) & ~bad[label]
    out = normals.copy()
    grouped = keep & (size[label] > 1)
    out[grouped] = total[label[grouped]] / length[label[grouped], None]
    dropped = int(np.sum(size[bad]))
    merged = n - int(keep.sum()) - dropped
    return points[keep], out[keep], merged, dropped
