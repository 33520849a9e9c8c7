"""Walls inside the solid, kept in the output as thin cavities.

A sample whose winding number reads inside on both of its sides (`jaxrbf._winding.buried_samples`:
where a teapot's spout pierces its body, an eyeball's rim is sunk in its socket) lies on a wall
that the closed surface of the fit cannot pass through without a bubble, so the fit leaves it out
and closes the pieces' union. The wall is still part of the input, though, and of the surface the
input came from: left out, a 100k-sample suzanne lost half of each eyeball (3% of the true
surface 1.5% of the diagonal from the output; Chamfer-L1 0.125% against Poisson's 0.118%), and a
100k-sample teapot the inner end of its spout (2.2%; 0.119% against 0.114%). Poisson keeps such
walls as slivers of its indicator.

`wall_cavities` meshes each wall as the boundary of a thin slab of empty space around it, inside
the solid, on a grid of its own (`GRID`, finer than the meshing grid): the points within
`HALF_WIDTH` cells of that grid from the wall's local plane (the mean of its `NEIGHBOURS`
nearest wall samples and of their normals, so that both faces of the slab are as smooth as the
wall; a union of balls round the samples, tried first, left both faces dimpled at the samples'
spacing: normal consistency 0.966 against 0.975 on that suzanne), no farther than `REACH` point
spacings from a wall sample nor past the wall's edge (`EDGE`), and where the fit reads at least
`DEPTH` half-widths inside, so that a wall meets the outer surface without cutting a slot in it
and a sample wrongly called buried on the outer surface leaves no dent. Each cavity is closed,
its faces turned into the cavity, so the output stays watertight: a solid with thin voids,
every input sample on or next to its surface.

Precision: the slab's fields are float64 on the host (k-d tree queries and plane distances); the
fit is read through the model (its own precision), in batches of a fixed size (one compilation).
"""

from __future__ import annotations

import math

import numpy as np

#: The cavities' own grid: cells of GRID x the smaller of the point spacing and the meshing
#: cell. A slab's faces lie half its thickness from the wall, so the thickness decides how far
#: from the true wall they are: first tried at 1.25 x the larger of spacing and meshing cell,
#: they lay 0.4-1% of the diagonal off at 10k samples of a teapot or suzanne and cost 0.6-2%
#: of precision at 0.5% (below Poisson's); at 0.75 the suzanne 10k still fell short (99.21%
#: against Poisson's 99.37%), at 0.5 it does not (99.42%).
GRID = 0.5
#: Half the slab's thickness, in its grid's cells: enough for marching cubes to keep it whole.
HALF_WIDTH = 1.25
#: How far past each wall sample a slab reaches (the radius of a ball round each), in point
#: spacings: it bridges the gaps between random samples. At 1.5 the slabs broke into more
#: pieces, whose rims cost normal consistency (suzanne 100k: 0.9731, teapot 100k 0.9829,
#: against Poisson's 0.9742 and 0.9848; at 2: 0.9777 and 0.9868).
REACH = 2.0
#: Where a slab ends at the wall's edge: where the mean of the nearest wall samples lies more
#: than EDGE point spacings sideways from the point (inside the wall they surround it).
EDGE = 2.0
#: How deep inside the fit's surface a cavity must lie, in half-widths (f < -DEPTH x width):
#: clear of the outer surface by its own thickness, so that a few samples of the outer surface
#: called buried (whose mean plane lies a little inside a convex surface) leave no shell
#: under it.
DEPTH = 2.0
#: Wall samples whose mean plane a slab follows.
NEIGHBOURS = 8
#: A wall of fewer samples than this makes no cavity: a few samples read buried in a sharp
#: crease of the outer surface (suzanne: clusters of 1-20 samples in its notches), where a
#: cavity would be a bubble a spacing across.
MIN_SAMPLES = 30
#: Pieces of a cavity with less area than CRUMB x MIN_SAMPLES squared point spacings are
#: dropped (`_without_crumbs`).
CRUMB = 1.0
#: Wall samples closer than LINK point spacings belong to one wall (one grid each). At 2 the
#: random samples of a narrow wall fell apart into groups below `MIN_SAMPLES` (the suzanne's
#: eyeball rims made no cavity).
LINK = 4.0
#: A wall's grid has at most this many cells along its longest side (coarser cells beyond, and
#: the slab grows thicker with them).
MAX_SIDE = 256
#: A shell's slab grid: cells of SHELL_GRID point spacings (not the meshing cell: the slab's
#: faces are put on the samples' local plane after marching, so a finer grid adds faces, not
#: accuracy: on a sphere with 20% cut away, 10k samples, the meshing cell of 0.4 spacings gave
#: 816k faces at Chamfer-L1 0.118% / precision 99.86%, one spacing 277k (3.5x faster) at
#: 0.128% / 99.84%, Poisson 0.42% / 88%), at most SHELL_MAX_SIDE cells along its longest side
#: (a slab has two faces: 256 cells give about as many vertices as Poisson depth 9. At 100k
#: samples, 512 against 256: the cut sphere 1.36M against 479k vertices, 76 against 39 s,
#: Chamfer-L1 0.111% against 0.115% (Poisson 0.424%, 209k vertices); the beetle 475k against
#: 123k vertices, 38 against 25 s, 0.088% / NC 0.982 against 0.098% / 0.980 (Poisson 4.79% /
#: 0.891, 216k)).
SHELL_GRID, SHELL_MAX_SIDE = 1.0, 256
#: A shell's slab follows the plane of its SHELL_NEIGHBOURS nearest samples weighted by
#: exp(-(d / (SHELL_SMOOTH spacings))^2).
SHELL_NEIGHBOURS, SHELL_SMOOTH = 24, 1.5
SHELL_REACH = 4.0
#: The slab marched on its grid is then squeezed to this share of its thickness.
SHELL_SQUEEZE = 0.1
#: Points per evaluation of a fit that has no bulk evaluator.
BATCH = 16384


def _walls(points: np.ndarray, link: float) -> list[np.ndarray]:
    """Index arrays of the groups of `points` joined by links shorter than `link`."""
    from ._prepare import linked_groups

    return _grouped(linked_groups(points, link)[1])


def _grouped(label: np.ndarray) -> list[np.ndarray]:
    """Index arrays of the points of each label (0 .. max)."""
    order = np.argsort(label, kind="stable")
    return np.split(order, np.cumsum(np.bincount(label))[:-1])


def _evaluate(model, x: np.ndarray) -> np.ndarray:
    """The fit at `x` (host float64): through the model's own bulk evaluator where it has one
    (a partition of unity, as `polygonize` reads it), else in batches of `BATCH` points padded
    to that size (one compilation)."""
    import jax.numpy as jnp

    from ._polygonize import _BULK_CHUNK, _bulk

    out = np.empty(len(x))
    bulk = _bulk(model)
    step = _BULK_CHUNK if bulk else BATCH
    for i in range(0, len(x), step):
        q = x[i : i + step]
        m = len(q)
        if bulk:
            out[i : i + m] = bulk(q)[0]
            continue
        if m < BATCH:
            q = np.concatenate([q, np.repeat(q[:1], BATCH - m, axis=0)])
        out[i : i + m] = np.asarray(model(jnp.asarray(q)), dtype=float)[:m]
    return out


def _local_plane(tree, p, n, q, k: int, smooth=None):
    """The plane of the `k` samples (`p`, normals `n`, k-d tree `tree`) nearest each of `q`:
    the offset of each query from their mean, its component along their mean normal, and that
    normal. `smooth`: weights exp(-(distance / smooth)^2) (relative to the nearest, so that they
    do not underflow), else equal."""
    dk, idx = tree.query(q, k=k, workers=-1)
    idx, dk = idx.reshape(len(q), k), dk.reshape(len(q), k)
    if smooth is None:
        wt = np.full((len(q), k), 1.0 / k)
    else:
        wt = np.exp(-(((dk - dk[:, :1]) / smooth) ** 2))
        wt /= wt.sum(axis=1, keepdims=True)
    nn = n[idx]
    # the normals of a wall's two faces may disagree in sign: align them with the nearest
    nn = nn * np.sign(np.einsum("ijk,ik->ij", nn, nn[:, 0]))[..., None]
    nn = np.einsum("ijk,ij->ik", nn, wt)
    nn /= np.maximum(np.linalg.norm(nn, axis=1, keepdims=True), 1e-300)
    off = q - np.einsum("ijk,ij->ik", p[idx], wt)
    return off, np.einsum("ij,ij->i", off, nn), nn


def _slab_field(
    model,
    p,
    n,
    width: float,
    spacing: float,
    h: float,
    lo,
    shape,
    smooth=None,
    reach=REACH,
    tree=None,
):
    """The field whose negative region is the cavity round one wall (samples `p`, normals `n`)
    on the grid of spacing `h` from `lo` with `shape` cells, border cells positive; with
    `model` None, the slab alone (a shell's, `shell_slabs`: not held inside any solid).
    `smooth`: weigh the nearest samples' planes by exp(-(distance / smooth)^2) (a smooth
    field, whose faces' normals vary smoothly) instead of equally. `tree`: a `cKDTree` of `p`
    to reuse."""
    from scipy.spatial import cKDTree

    tree = cKDTree(p) if tree is None else tree
    reach = reach * spacing
    k = min(NEIGHBOURS if smooth is None else SHELL_NEIGHBOURS, len(p))
    field = np.full(shape, h)
    flat = field.reshape(-1)
    ys = lo[1] + h * np.arange(shape[1])
    zs = lo[2] + h * np.arange(shape[2])
    yz = np.stack(np.meshgrid(ys, zs, indexing="ij"), -1).reshape(-1, 2)
    slice_size = shape[1] * shape[2]
    pending, points = [], []
    for i in range(1, shape[0] - 1):  # one x-slice at a time: memory grows with a slice
        x = np.column_stack([np.full(len(yz), lo[0] + h * i), yz])
        d, _ = tree.query(x, distance_upper_bound=reach + h, workers=-1)
        near = np.flatnonzero(d < reach + h)
        if len(near) == 0:
            continue
        q = x[near]
        off, along, nn = _local_plane(tree, p, n, q, k, smooth)
        slab = np.abs(along) - width
        # past the wall's edge its nearest samples all lie on one side: their mean is off
        # sideways by more than within the wall, where they surround the point
        side = np.linalg.norm(off - along[:, None] * nn, axis=1) - EDGE * spacing
        value = np.maximum(np.maximum(d[near] - reach, slab), side)
        flat[i * slice_size + near] = value
        inside = value < h  # only there can the fit change the sign
        pending.append(i * slice_size + near[inside])
        points.append(q[inside])
    if pending and model is not None:
        at = np.concatenate(pending)
        # one pass of the fit over every candidate, in batches of one size
        flat[at] = np.maximum(flat[at], _evaluate(model, np.concatenate(points)) + DEPTH * width)
    field[:, [0, -1]] = h
    field[:, :, [0, -1]] = h
    return field


def _without_crumbs(v: np.ndarray, f: np.ndarray, spacing: float):
    """The mesh `(v, f)` without its pieces of less area than `CRUMB` x `MIN_SAMPLES` squared
    point spacings: bits a slab shed where its wall curves or thins, smaller than the cavity of
    a wall of `MIN_SAMPLES` samples (which has about twice their area, both faces)."""
    from ._polygonize import _components, _keep_components

    k, label = _components(v, f)
    if k == 1:
        return v, f
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    piece = np.bincount(label[f[:, 0]], weights=area, minlength=k)
    return _keep_components(v, f, label, piece >= CRUMB * MIN_SAMPLES * spacing**2)


def wall_cavities(model, walls, normals, spacing: float, cell: float):
    """Thin closed cavities round the `walls` (buried samples, (k, 3), with their `normals`)
    inside the solid of `model` (see the module docstring), as `(vertices, faces, count)`: the
    cavities' faces turned into them, and how many cavities were meshed."""
    return _slabs(model, walls, normals, spacing, cell)


def _slabs(model, points, normals, spacing: float, cell: float):
    """The slabs round each linked group of `points` (`wall_cavities` inside `model`; with
    `model` None, `shell_slabs`), as `(vertices, faces, count)`."""
    from scipy.spatial import cKDTree

    from ._polygonize import marched

    p = np.asarray(points, dtype=float).reshape(-1, 3)
    n = np.asarray(normals, dtype=float).reshape(-1, 3)
    spacing = float(spacing)
    shell = model is None
    grid, max_side, reach = (
        (SHELL_GRID, SHELL_MAX_SIDE, SHELL_REACH) if shell else (GRID, MAX_SIDE, REACH)
    )
    fine = grid * min(spacing, float(cell)) if cell > 0 and not shell else grid * spacing
    verts, faces, count, offset = [], [], 0, 0
    if len(p) < MIN_SAMPLES or not fine > 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), 0
    smooth = SHELL_SMOOTH * spacing if shell else None
    if shell:
        # a shell can be the whole input: its pieces as `shell_samples` found them (a k-nearest
        # graph, whose size does not grow with the density as all pairs within LINK would)
        from ._winding import pieces

        groups = _grouped(pieces(p, spacing))
    else:
        groups = _walls(p, LINK * spacing)
    for idx in groups:
        if len(idx) < MIN_SAMPLES:
            continue
        wp, wn = p[idx], n[idx]
        h = max(fine, float(np.max(np.ptp(wp, axis=0)) + 2 * reach * spacing) / max_side)
        width = HALF_WIDTH * h
        lo = wp.min(axis=0) - reach * spacing - 2 * h
        hi = wp.max(axis=0) + reach * spacing + 2 * h
        shape = tuple(int(s) for s in np.ceil((hi - lo) / h).astype(int) + 1)
        tree = cKDTree(wp)
        field = _slab_field(model, wp, wn, width, spacing, h, lo, shape, smooth, reach, tree)
        if not field.min() < 0:
            continue
        v, f = marched(field, 0.0, h, lo)
        # marched turns the faces up the field's gradient, out of the slab: a cavity's face
        # into it
        v, f = _without_crumbs(v, f if shell else f[:, ::-1], spacing)
        if len(f) == 0:
            continue
        if shell:
            # the slab squeezed towards its samples' plane along the plane's normal (a
            # monotone map along each normal: no fold), so that its faces lie SHELL_SQUEEZE of
            # the grid's half-width from the samples
            _, along, nn = _local_plane(tree, wp, wn, v, min(SHELL_NEIGHBOURS, len(wp)), smooth)
            v = v - ((1.0 - SHELL_SQUEEZE) * along)[:, None] * nn
        verts.append(v)
        faces.append(f + offset)
        offset += len(v)
        count += 1
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), 0
    return np.concatenate(verts), np.concatenate(faces).astype(np.int64), count


def with_cavities(mesh, model, walls, normals, spacing: float, cell: float, verbose=False):
    """`mesh` with the cavities of `wall_cavities` added (the mesh itself when there are none)."""
    if walls is None or len(walls) == 0 or not math.isfinite(spacing):
        return mesh
    v, f, count = wall_cavities(model, walls, normals, spacing, cell)
    if verbose:
        from ._constraints import log

        log(
            f"{len(walls):,} buried samples (walls inside the solid): kept in the output as "
            f"{count} thin {'cavity' if count == 1 else 'cavities'} of {len(f):,} faces"
            if count
            else f"{len(walls):,} buried samples (walls inside the solid): no cavity (too few or "
            "too near the outer surface)"
        )
    return _joined(mesh, v, f)


def _joined(mesh, v: np.ndarray, f: np.ndarray):
    """`mesh` with the mesh `(v, f)` beside it (`mesh` itself when `f` is empty)."""
    from .io import Mesh

    if len(f) == 0:
        return mesh
    base = np.asarray(mesh.vertices).reshape(-1, 3)
    faces = np.asarray(mesh.faces).reshape(-1, 3)
    return Mesh(np.concatenate([base, v]), np.concatenate([faces, f + len(base)]))


def shell_slabs(shells, normals, spacing: float, cell: float):
    """Thin closed slabs round the `shells` (samples of pieces that bound no volume, (k, 3),
    with their `normals`: `jaxrbf._winding.shell_samples`), as `(vertices, faces, count)`: each
    linked piece's slab (the points within a half-width of its local plane, as a cavity's, but
    solid and standing on its own, its plane weighted smoothly, `SHELL_SMOOTH`, then squeezed,
    `SHELL_SQUEEZE`), its faces turned out, and how many slabs were meshed."""
    return _slabs(None, shells, normals, spacing, cell)


def with_shells(mesh, shells, normals, spacing: float, cell: float, verbose=False):
    """`mesh` with the slabs of `shell_slabs` round the `shells` added."""
    if shells is None or len(shells) == 0 or not math.isfinite(spacing):
        return mesh
    v, f, count = shell_slabs(shells, normals, spacing, cell)
    if verbose:
        from ._constraints import log

        log(
            f"{len(shells):,} samples on open shells: {count} thin "
            f"{'slab' if count == 1 else 'slabs'} of {len(f):,} faces round them"
        )
    return _joined(mesh, v, f)
