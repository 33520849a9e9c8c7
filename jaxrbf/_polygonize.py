"""Zero sets to meshes and curves: the grid is sampled in JAX (fixed-size chunks, jit), then
scikit-image's marching cubes / find_contours run on the host. Works on any implicit: a JAX-traceable
callable mapping (n, d) points to (n,) values. Large 3-D grids are meshed in a narrow band around
the surface (`polygonize(..., narrow_band=True)`)."""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from dataclasses import dataclass
from itertools import product

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._errors import InputError
from ._project import project as _project
from ._util import available_memory as _available_memory
from ._util import check_memory

_CHUNK = 2**15
#: Points per call of an implicit's own bulk evaluator (see `_bulk`).
_BULK_CHUNK = 2**17


def _bulk(implicit):
    """The implicit's host-level evaluator `evaluate_many(points, grad) -> (f, grad f or None)`
    (numpy in, numpy out) where it has one, else None. Partition-of-unity models have one: it
    evaluates patch by patch, several times faster than gathering every point's patches."""
    fn = getattr(implicit, "evaluate_many", None)
    return fn if callable(fn) else None


def _bounds(implicit, bounds, dim: int | None, padding: float):
    if bounds is None:
        if not hasattr(implicit, "bounds"):
            raise InputError(
                "`bounds` is needed for an implicit that does not know its extent: "
                "give bounds=(lo, hi), e.g. ((-1, -1, -1), (1, 1, 1))"
            )
        lo, hi = (np.asarray(b, dtype=float) for b in implicit.bounds())
        pad = padding * (hi - lo).max()
        lo, hi = lo - pad, hi + pad
    else:
        try:
            lo, hi = (np.asarray(b, dtype=float).reshape(-1) for b in bounds)
        except (TypeError, ValueError):
            raise InputError("`bounds` must be a pair (lo, hi) of coordinate tuples") from None
    if lo.shape != hi.shape or (dim is not None and lo.shape != (dim,)):
        raise InputError(
            f"`bounds` must be two points of dimension {dim}, got {lo.shape} and {hi.shape}"
        )
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
        raise InputError(
            f"`bounds` must be finite with hi > lo on every axis, got lo={lo}, hi={hi}"
        )
    return lo, hi


def _grid_shape(lo, hi, resolution) -> tuple[np.ndarray, tuple[int, ...]]:
    ext = hi - lo
    if np.ndim(resolution) == 0:
        res = int(resolution)
        if res < 2:
            raise InputError(f"`resolution` must be at least 2 samples, got {resolution}")
        h = ext.max() / (res - 1)
        shape = tuple(int(np.ceil(e / h)) + 1 for e in ext)
        return np.full(len(ext), h), shape
    res = tuple(int(r) for r in resolution)
    if len(res) != len(ext) or min(res) < 2:
        raise InputError(f"`resolution` must be an int or {len(ext)} ints >= 2, got {resolution}")
    return ext / (np.array(res) - 1), res


@eqx.filter_jit
def _eval_chunk(implicit, lo, h, shape, start, chunk: int):
    idx = start + jnp.arange(chunk)
    coords = []
    rest = idx
    for k in range(len(shape) - 1, -1, -1):
        coords.append(rest % shape[k])
        rest = rest // shape[k]
    ijk = jnp.stack(coords[::-1], axis=1)
    pts = lo + ijk * h
    return implicit(pts)


def sample_grid(
    implicit: Callable, lo, hi, resolution, *, progress: bool | None = None, desc: str = "sampling"
) -> tuple[np.ndarray, np.ndarray]:
    """Values of `implicit` on a regular grid over [lo, hi] (float64 on the host).

    **Returns:** `(values, spacing)`: an array of the grid's shape (axis k = coordinate k) and the
    spacing per axis.
    """
    from tqdm import tqdm

    spacing, shape = _grid_shape(np.asarray(lo, float), np.asarray(hi, float), resolution)
    total = int(np.prod(shape))
    out = np.empty(total)
    bulk = _bulk(implicit)
    chunk = _BULK_CHUNK if bulk else _CHUNK
    n_chunks = -(-total // chunk)
    disable = (not sys.stderr.isatty()) if progress is None else not progress
    lo_j, h_j = jnp.asarray(lo, dtype=float), jnp.asarray(spacing)
    for c in tqdm(range(n_chunks), desc=desc, unit="chunk", disable=disable, file=sys.stderr):
        start = c * chunk
        end = min(start + chunk, total)
        if bulk:
            ijk = np.stack(np.unravel_index(np.arange(start, end), shape), axis=1)
            out[start:end] = bulk(np.asarray(lo, float) + ijk * spacing)[0]
            continue
        vals = np.asarray(_eval_chunk(implicit, lo_j, h_j, shape, jnp.asarray(start), chunk))
        out[start:end] = vals[: end - start]
    out = out.reshape(shape)
    bad = ~np.isfinite(out)
    if bad.any():
        raise InputError(
            f"the implicit returned NaN or infinite values at {int(bad.sum())} of {total} grid points"
        )
    return out, spacing


# ---------------------------------------------------------------------------------------------
# Narrow band: a coarse pass finds the cells near the surface, only their fine samples are
# evaluated, and marching cubes runs brick by brick on volumes whose other samples hold a
# sentinel of the known sign. The mesh equals the dense one (same vertices, to the float32
# rounding marching cubes itself applies, and the same faces) wherever the coarse pass found
# every cell the surface crosses.
# ---------------------------------------------------------------------------------------------

_AUTO_BAND = 160  # narrow_band=None: narrow band when the longest side has more samples than this
_BRICK = 64  # fine cells per side of a brick (the unit marching cubes runs on)
_DILATE = 1  # coarse cells added around the marked ones, on every side
_DENSE_BYTES = 16  # host bytes per sample of the dense path: float64 grid, float32 copy, masks
_EPS = float(np.spacing(1.0))  # scikit-image's FLT_EPSILON (it is a double's epsilon there)


@dataclass(frozen=True)
class BandStats:
    """What one narrow-band `polygonize` evaluated (see `last_band_stats`).

    **Fields:**
    - `shape`: samples per axis of the fine grid (never allocated as a whole).
    - `cell`: fine cells per side of the band's cells (`coarsening` halved `refine` times).
    - `gradient_samples`: samples evaluated with their gradients: the coarse grid and the samples
      of each refinement inside the previous band.
    - `band_samples`: distinct fine samples evaluated in the band.
    - `band_cells`, `cells`: cells of size `cell` in the band (after dilation), and in the box.
    - `bricks`: bricks meshed.
    """

    shape: tuple[int, ...]
    cell: int
    gradient_samples: int
    band_samples: int
    band_cells: int
    cells: int
    bricks: int

    @property
    def grid_samples(self) -> int:
        """Samples of the full fine grid (what the dense path evaluates)."""
        return int(np.prod(self.shape))

    @property
    def evaluated(self) -> int:
        """Points the implicit was evaluated at: `gradient_samples` + `band_samples`."""
        return self.gradient_samples + self.band_samples

    @property
    def fraction(self) -> float:
        """`evaluated` as a fraction of `grid_samples`."""
        return self.evaluated / self.grid_samples


_last_stats: BandStats | None = None


def last_band_stats() -> BandStats | None:
    """The `BandStats` of the latest narrow-band `polygonize` in this process (None before any)."""
    return _last_stats


@eqx.filter_jit
def _eval_points(implicit, lo, h, ijk):
    """f at the grid samples `ijk` (a fixed-size (chunk, 3) block of integer indices)."""
    return implicit(lo + ijk * h)


@eqx.filter_jit
def _eval_points_grad(implicit, lo, h, ijk):
    """f and grad f at the grid samples `ijk`, from three forward-mode derivatives (`jax.jvp`):
    they run inside the implicit's own blocks, where reverse mode over a blocked implicit would
    keep every block's intermediates (3-4x slower on an `RBFModel`)."""
    p = lo + ijk * h
    cols = []
    for e in jnp.eye(3, dtype=p.dtype):
        f, df = jax.jvp(implicit, (p,), (jnp.broadcast_to(e, p.shape),))
        cols.append(df)
    return f, jnp.stack(cols, axis=1)


def _padded(ijk: np.ndarray) -> jax.Array:
    block = np.zeros((_CHUNK, 3), np.int32)
    block[: len(ijk)] = ijk
    return jnp.asarray(block)


def _human(n: float) -> str:
    for size, unit in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if n >= size:
            return f"{n / size:.3g}{unit}"
    return str(int(n))


def _dilate(mask: np.ndarray, steps: int) -> np.ndarray:
    """Grow a boolean grid by `steps` cells along every axis and diagonal (a cube)."""
    for _ in range(steps):
        for k in range(mask.ndim):
            grown = mask.copy()
            lead = (slice(None),) * k
            grown[lead + (slice(1, None),)] |= mask[lead + (slice(None, -1),)]
            grown[lead + (slice(None, -1),)] |= mask[lead + (slice(1, None),)]
            mask = grown
    return mask


def _corners(a: np.ndarray, nc) -> list[np.ndarray]:
    """The 8 corner views of a (nc + 1)-grid, each of shape nc (cell (i, j, k)'s corners)."""
    return [a[i : i + nc[0], j : j + nc[1], k : k + nc[2]] for i, j, k in product((0, 1), repeat=3)]


@dataclass
class _Plan:
    """The coarse levels' result: which cells (of the finest level) hold the band, and on which
    side of the level every sample of that level lies."""

    shape: tuple[int, ...]
    c: int  # fine cells per side of the finest coarse level's cells
    nc: np.ndarray  # its cells per axis
    marked: np.ndarray  # bool, shape nc: cells whose fine samples are evaluated
    above: np.ndarray  # bool, shape nc + 1: sample above `level` (as marching cubes sees it)
    vmin: float
    vmax: float
    sentinels: tuple[np.float32, np.float32]  # fill values below / above the level
    gradient_samples: int  # samples evaluated with their gradients, all levels


def _level_positions(n: np.ndarray, c: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """Cells per axis of the level with cells of c fine cells, and the fine index of each of its
    samples per axis (sample i is fine sample c * i; the last one is clamped onto the grid's end)."""
    nc = np.maximum(-(-(n - 1) // c), 1)
    return nc, [np.minimum(c * np.arange(m + 1), k - 1) for m, k in zip(nc, n, strict=True)]


def _in_closure(marked: np.ndarray, c: int, pos: list[np.ndarray]) -> np.ndarray:
    """Which samples (fine indices `pos` per axis, a grid) lie in a closed cell marked in `marked`
    (cells of c fine cells): fine index p lies in cells p // c and, when p is a multiple of c,
    p // c - 1."""
    nc = marked.shape
    cand = []
    for k, p in enumerate(pos):
        q = p // c
        cand.append(
            ((np.minimum(q, nc[k] - 1), q < nc[k]), (np.maximum(q - 1, 0), (q >= 1) & (p == c * q)))
        )
    out = np.zeros(tuple(len(p) for p in pos), bool)
    for (i, vi), (j, vj), (k, vk) in product(*cand):
        valid = vi[:, None, None] & vj[None, :, None] & vk[None, None, :]
        out |= valid & marked[np.ix_(i, j, k)]
    return out


def _value_distance(implicit, lo, spacing, ijk, level, disable, desc):
    """f and the distance estimate |f - level| / |grad f| at the fine samples `ijk` (E, 3)."""
    from tqdm import tqdm

    total = len(ijk)
    vals, dist = np.empty(total), np.empty(total)
    lo_j, h_j = jnp.asarray(lo, dtype=float), jnp.asarray(spacing)
    bulk = _bulk(implicit)
    chunk = _BULK_CHUNK if bulk else _CHUNK
    for start in tqdm(
        range(0, total, chunk), desc=desc, unit="chunk", disable=disable, file=sys.stderr
    ):
        end = min(start + chunk, total)
        if bulk:
            f, g = bulk(np.asarray(lo, float) + ijk[start:end] * spacing, True)
        else:
            f, g = _eval_points_grad(implicit, lo_j, h_j, _padded(ijk[start:end]))
            f, g = np.asarray(f)[: end - start], np.asarray(g)[: end - start]
        gnorm = np.linalg.norm(g, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):  # inf where grad f = 0
            dist[start:end] = np.where(gnorm == 0, np.inf, np.abs(f - level) / gnorm)
        vals[start:end] = f
    bad = ~np.isfinite(vals)
    if bad.any():
        raise InputError(
            f"the implicit returned NaN or infinite values at {int(bad.sum())} of {total} "
            "coarse grid points"
        )
    return vals, dist


def _coarse_pass(implicit, lo, spacing, shape, level, sizes, band_width, disable) -> _Plan:
    """Mark the cells that may hold the surface, level by level (cell sizes `sizes`, each
    dividing the previous): at the first level everywhere, at the next ones inside the cells
    marked by the previous level only."""
    n = np.asarray(shape)
    marked = above = prev = None
    vmin, vmax, scale, count = np.inf, -np.inf, 0.0, 0
    for depth, c in enumerate(sizes):
        if marked is not None and not marked.any():
            break
        nc, pos = _level_positions(n, c)
        if marked is None:
            todo = np.ones(tuple(nc + 1), bool)
            new_above = np.zeros(tuple(nc + 1), bool)
            inside = np.ones(tuple(nc), bool)
        else:
            # samples outside the previous band keep its side; cells outside stay unmarked
            todo = _in_closure(marked, prev, pos)
            new_above = above[np.ix_(*[p // prev for p in pos])]
            inside = marked[np.ix_(*[(c * np.arange(m)) // prev for m in nc])]
        idx = np.argwhere(todo)
        ijk = np.stack([pos[k][idx[:, k]] for k in range(3)], axis=1)
        desc = "meshing: coarse grid" if depth == 0 else f"meshing: level {depth + 1}"
        vals, d = _value_distance(implicit, lo, spacing, ijk, level, disable, desc)
        count += len(vals)
        vmin, vmax = min(vmin, float(vals.min())), max(vmax, float(vals.max()))
        scale = max(scale, float(np.abs(vals - level).max()))
        # marching cubes compares float32(f) with the level in double precision: so does the band
        new_above[todo] = vals.astype(np.float32).astype(np.float64) > level
        dist = np.full(tuple(nc + 1), np.inf)
        dist[todo] = d
        # a cell may hold the surface when its corners lie on both sides of the level, or when
        # one corner's distance estimate is below band_width diagonals (NaN counts as near)
        corners = _corners(new_above, nc)
        hit = np.zeros(tuple(nc), bool)
        for a in corners[1:]:
            hit |= a != corners[0]
        near = ~(dist >= band_width * float(np.linalg.norm(c * np.asarray(spacing))))
        for a in _corners(near, nc):
            hit |= a
        marked = _dilate(hit & inside, _DILATE)
        above, prev = new_above, c
    # sentinels: far from the level, of a sign marching cubes reads correctly after float32
    scale = scale or 1.0
    while not (
        np.float64(np.float32(level + scale)) > level
        and np.float64(np.float32(level - scale)) <= level
    ):
        scale *= 2
    sentinels = (np.float32(level - scale), np.float32(level + scale))
    return _Plan(tuple(int(k) for k in n), prev, nc, marked, above, vmin, vmax, sentinels, count)


@dataclass
class _Layout:
    """The band's fine samples, grouped by the coarse cell that owns them: cell o owns the fine
    samples c * o + r, r in [0, c)^3 (the cells one past the last hold the grid's far faces)."""

    owners: np.ndarray  # (K, 3) owning cells
    slot: np.ndarray  # int, shape nc + 1: row of each owner in `owners`, K where none
    inband: np.ndarray  # (K, c^3) bool: sample evaluated (it lies in a marked cell, closed)
    local: np.ndarray  # (c^3, 3) offsets r in C order


def _layout(plan: _Plan) -> _Layout:
    c, nc, n = plan.c, plan.nc, np.asarray(plan.shape)
    shifts = list(product((0, 1), repeat=3))
    padded = np.pad(plan.marked, 1)  # padded[o - e + 1] = marked[o - e], False off the grid
    owned = np.zeros(tuple(nc + 1), bool)
    for e in shifts:
        owned |= padded[tuple(slice(1 - d, 2 - d + m) for d, m in zip(e, nc, strict=True))]
    owners = np.argwhere(owned)
    slot = np.full(tuple(nc + 1), len(owners), np.int32)
    slot[tuple(owners.T)] = np.arange(len(owners))
    local = np.stack(np.unravel_index(np.arange(c**3), (c, c, c)), axis=1)
    # sample c*o + r lies in the closed cell o - e when e_k = 1 only where r_k = 0
    inband = np.zeros((len(owners), c**3), bool)
    for e in shifts:
        cell = padded[tuple((owners - np.asarray(e) + 1).T)]
        allowed = np.all((np.asarray(e) == 0) | (local == 0), axis=1)
        inband |= cell[:, None] & allowed[None, :]
    for k in range(3):
        inband &= owners[:, k, None] * c + local[None, :, k] <= n[k] - 1
    return _Layout(owners, slot, inband, local)


def _band_batches(layout: _Layout, c: int, chunk: int = _CHUNK):
    """Fixed-size batches of the band's samples: (owner rows, local offsets, global indices)."""
    per = layout.inband.shape[1]
    cum = np.concatenate([[0], np.cumsum(layout.inband.sum(axis=1))])
    for s0 in range(0, int(cum[-1]), chunk):
        s1 = min(s0 + chunk, int(cum[-1]))
        a = int(np.searchsorted(cum, s0, "right")) - 1
        b = int(np.searchsorted(cum, s1, "left"))
        flat = np.flatnonzero(layout.inband[a:b])[s0 - cum[a] : s1 - cum[a]]
        rows, loc = a + flat // per, flat % per
        yield rows, loc, layout.owners[rows] * c + layout.local[loc]


def _evaluate_band(implicit, lo, spacing, plan: _Plan, layout: _Layout, disable):
    """float32 values of the band's samples by owner row (NaN elsewhere, and in a last row for
    `slot`'s "no owner"), and the float64 range of all values seen."""
    from tqdm import tqdm

    k, per = layout.inband.shape
    vals = np.full((k + 1, per), np.nan, np.float32)
    n_band = int(layout.inband.sum())
    lo_j, h_j = jnp.asarray(lo, dtype=float), jnp.asarray(spacing)
    state = {"bad": 0, "vmin": plan.vmin, "vmax": plan.vmax}

    def collect(rows, loc, out):
        v = np.asarray(out)[: len(rows)]
        finite = np.isfinite(v)
        state["bad"] += int((~finite).sum())
        if finite.any():
            state["vmin"] = min(state["vmin"], float(v[finite].min()))
            state["vmax"] = max(state["vmax"], float(v[finite].max()))
        vals[rows, loc] = v

    bulk = _bulk(implicit)
    chunk = _BULK_CHUNK if bulk else _CHUNK
    pending = None  # one batch in flight: the host prepares the next while the device works
    for rows, loc, ijk in tqdm(
        _band_batches(layout, plan.c, chunk),
        total=-(-n_band // chunk),
        desc="meshing: band",
        unit="chunk",
        disable=disable,
        file=sys.stderr,
    ):
        if bulk:
            out = bulk(np.asarray(lo, float) + ijk * spacing)[0]
        else:
            out = _eval_points(implicit, lo_j, h_j, _padded(ijk))
        if pending is not None:
            collect(*pending)
        pending = (rows, loc, out)
    if pending is not None:
        collect(*pending)
    if state["bad"]:
        raise InputError(
            f"the implicit returned NaN or infinite values at {state['bad']} of {n_band} "
            "evaluated grid points"
        )
    return vals, state["vmin"], state["vmax"]


def _grid_vertices(v32: np.ndarray, vol: np.ndarray, origin: np.ndarray, level: float):
    """Vertices of a brick in global grid coordinates, float32, exactly as marching cubes on the
    whole grid rounds them: it interpolates in double and rounds x + t to float32, so shifting the
    brick's rounded x + t would round twice. The interpolation is redone (scikit-image's
    formula, on the same float32 samples) where the vertex's cell is certain; elsewhere (a vertex
    on a sample) the shifted value is already exact."""
    out = (v32.astype(np.float64) + origin).astype(np.float32)
    frac = v32 != np.floor(v32)
    nfrac = frac.sum(axis=1)
    cell = np.floor(v32).astype(np.int64)

    def weight(idx):
        v = vol[tuple(idx.T)].astype(np.float64) - level
        return 1.0 / (_EPS + np.abs(v))

    # on a grid edge (one fractional coordinate): t = w_hi / (w_lo + w_hi)
    sel = np.flatnonzero(nfrac == 1)
    if len(sel):
        axis = np.argmax(frac[sel], axis=1)
        a = cell[sel]
        b = a.copy()
        b[np.arange(len(sel)), axis] += 1
        wa, wb = weight(a), weight(b)
        t = wb / (wa + wb)
        x = a[np.arange(len(sel)), axis].astype(np.float64)
        same = (x + t).astype(np.float32) == v32[sel, axis]
        redo = ((x + origin[axis]) + t).astype(np.float32)
        out[sel[same], axis[same]] = redo[same]
    # inside a cell (Lewiner's extra vertex): the centre of mass of all 8 corners
    sel = np.flatnonzero(nfrac == 3)
    if len(sel):
        base = cell[sel]
        # scikit-image's corner order v0..v7 in its (x, y, z) = our axes (2, 1, 0)
        order = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1)]
        order.append((0, 1, 1))
        w = [weight(base + np.array([dz, dy, dx])) for dx, dy, dz in order]
        ff = np.zeros(len(sel))
        for wi in w:
            ff = ff + wi
        fx = ((w[1] + w[2]) + w[5]) + w[6]
        fy = ((w[2] + w[3]) + w[6]) + w[7]
        fz = ((w[4] + w[5]) + w[6]) + w[7]
        ok = np.ones(len(sel), bool)
        redo = np.empty((len(sel), 3), np.float32)
        for k, f in zip((0, 1, 2), (fz, fy, fx), strict=True):
            x = base[:, k].astype(np.float64)
            ok &= (x + f / ff).astype(np.float32) == v32[sel, k]
            redo[:, k] = ((x + origin[k]) + f / ff).astype(np.float32)
        out[sel[ok]] = redo[ok]
    return out


def _weld(verts: np.ndarray, faces: np.ndarray, seams: np.ndarray):
    """Merge the vertices that several bricks produced on their shared faces (`seams`: the
    candidates), by exact equality of their float32 grid coordinates."""
    cand = np.flatnonzero(seams)
    remap = np.arange(len(verts))
    if len(cand):
        keys = np.ascontiguousarray(verts[cand]).view(np.dtype((np.void, verts.itemsize * 3)))
        _, first, inverse = np.unique(keys.ravel(), return_index=True, return_inverse=True)
        remap[cand] = cand[first][inverse.ravel()]
    keep = remap == np.arange(len(verts))
    new = np.cumsum(keep) - 1
    return verts[keep], new[remap[faces]]


def _mesh_band(
    spacing, plan: _Plan, layout: _Layout, vals, level, disable
) -> tuple[np.ndarray, np.ndarray, float, int]:
    """Marching cubes brick by brick; returns welded float32 grid-coordinate vertices, faces,
    the orientation sum (as in the dense path) and the number of bricks meshed."""
    from skimage.measure import marching_cubes
    from tqdm import tqdm

    c, nc, n = plan.c, plan.nc, np.asarray(plan.shape)
    per_side = max(1, _BRICK // c)
    stride = c * per_side
    vals = vals.reshape(-1, c, c, c)
    bricks = np.unique(np.argwhere(plan.marked) // per_side, axis=0)
    pieces, count, offset, orient = [], 0, 0, 0.0
    lev = np.float64(level)
    for b in tqdm(bricks, desc="meshing: bricks", unit="brick", disable=disable, file=sys.stderr):
        o0 = b * per_side
        o1 = np.minimum(o0 + per_side, nc)  # owners o0..o1: their samples cover the brick
        s0 = o0 * c
        ext = np.minimum(o1 * c, n - 1) - s0 + 1
        sub = layout.slot[o0[0] : o1[0] + 1, o0[1] : o1[1] + 1, o0[2] : o1[2] + 1]
        vol = vals[sub].transpose(0, 3, 1, 4, 2, 5)
        vol = vol.reshape(sub.shape[0] * c, sub.shape[1] * c, sub.shape[2] * c)
        vol = vol[: ext[0], : ext[1], : ext[2]]
        known = ~np.isnan(vol)
        # a sample not evaluated lies only in unmarked cells, which are all on one side of the
        # level; the coarse sample at or below it is a corner of such a cell
        side = plan.above[np.ix_(*[(s0[k] + np.arange(ext[k])) // c for k in range(3)])]
        vol = np.where(known, vol, np.where(side, plan.sentinels[1], plan.sentinels[0]))
        vol = np.ascontiguousarray(vol, dtype=np.float32)
        up = vol > lev
        if up.all() or not up.any():
            continue
        # cubes whose samples were all evaluated are the only ones that can hold the surface
        v32, f, nrm, _ = marching_cubes(vol, level, allow_degenerate=True, mask=known)
        tri = v32.astype(np.float64)[f] * spacing
        fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        orient += float(np.sum(fn * nrm[f].sum(axis=1)))
        g32 = _grid_vertices(v32, vol, s0, level)
        # vertices on a face shared with another brick appear in both
        on = (g32 == np.round(g32)) & (np.round(g32) % stride == 0)
        on &= (g32 > 0) & (g32 < n - 1)
        pieces.append((g32, f.astype(np.int64) + offset, on.any(axis=1)))
        offset += len(g32)
        count += 1
    if not pieces:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int64), 0.0, 0
    verts, faces = _weld(
        np.concatenate([p[0] for p in pieces]),
        np.concatenate([p[1] for p in pieces]),
        np.concatenate([p[2] for p in pieces]),
    )
    return verts, faces, orient, count


def _sizes(coarsening: int, refine: int) -> list[int]:
    """Cell sizes of the coarse levels: `coarsening`, halved `refine` times (while even)."""
    sizes = [coarsening]
    while len(sizes) <= refine and sizes[-1] % 2 == 0:
        sizes.append(sizes[-1] // 2)
    return sizes


#: Host bytes per cell of a narrow band's coarse levels (a float64 distance and a few masks).
_COARSE_BYTES = 16


def grid_memory(shape, narrow_band: bool, coarsening: int = 8, refine: int = 1) -> int:
    """Bytes a grid of `shape` needs at least: every sample of a dense grid (`_DENSE_BYTES`
    each), or the coarse levels a narrow band allocates in full (its band itself grows with the
    surface's area and is not counted)."""
    if not narrow_band:
        return _DENSE_BYTES * math.prod(shape)
    sizes = _sizes(int(coarsening), int(refine))
    return sum(_COARSE_BYTES * math.prod(-(-s // c) + 1 for s in shape) for c in sizes)


def check_resolution(
    resolution,
    extent,
    *,
    narrow_band: bool | None = None,
    name: str = "`resolution`",
    coarsening: int = 8,
    refine: int = 1,
) -> tuple[int, ...]:
    """Refuse, before any work, a `resolution` whose grid over a box of `extent` (the box's side
    lengths) does not fit in memory; `name` is the option's name in the message (e.g.
    "--resolution"). `narrow_band` None: the rule of `polygonize` (on above 160 samples along
    the longest side, 3-D only). **Returns:** the grid's shape."""
    extent = np.asarray(extent, dtype=float)
    if np.ndim(resolution) == 0 and (isinstance(resolution, bool) or int(resolution) < 2):
        raise InputError(f"{name} must be at least 2 samples, got {resolution}")
    _, shape = _grid_shape(np.zeros_like(extent), extent, resolution)
    if narrow_band is None:
        narrow_band = len(shape) == 3 and max(shape) > _AUTO_BAND
    kind = "narrow-band " if narrow_band else ""
    check_memory(
        grid_memory(shape, bool(narrow_band), coarsening, refine),
        f"{name} {resolution} (a {kind}{'x'.join(map(str, shape))} grid)",
        f"lower {name}",
        avail=_available_memory(),
    )
    return shape


def _check_band_args(coarsening, refine, band_width) -> None:
    for name, value, least in (("coarsening", coarsening, 1), ("refine", refine, 0)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least:
            raise InputError(f"`{name}` must be an integer >= {least}, got {value!r}")
    if not (isinstance(band_width, (int, float)) and np.isfinite(band_width) and band_width > 0):
        raise InputError(f"`band_width` must be a positive number, got {band_width!r}")


def band_samples(
    implicit: Callable,
    resolution: int | tuple[int, int, int] = 128,
    bounds=None,
    *,
    level: float = 0.0,
    padding: float = 0.05,
    coarsening: int = 8,
    band_width: float = 1.5,
    refine: int = 1,
    progress: bool | None = None,
) -> tuple[np.ndarray, tuple[int, ...]]:
    """The fine grid samples a narrow-band `polygonize` with these arguments evaluates, found by
    its coarse pass alone (nothing else is evaluated).

    **Arguments:** as for `polygonize`.

    **Returns:** `(indices, shape)`: sorted flat (C-order) indices into the grid of `shape`.
    """
    _check_band_args(coarsening, refine, band_width)
    lo, hi = _bounds(implicit, bounds, 3, padding)
    spacing, shape = _grid_shape(lo, hi, resolution)
    disable = (not sys.stderr.isatty()) if progress is None else not progress
    sizes = _sizes(int(coarsening), int(refine))
    plan = _coarse_pass(implicit, lo, spacing, shape, float(level), sizes, band_width, disable)
    layout = _layout(plan)
    rows, loc = np.nonzero(layout.inband)
    ijk = layout.owners[rows] * plan.c + layout.local[loc]
    return np.sort(np.ravel_multi_index(tuple(ijk.T), shape)), shape


def _polygonize_band(implicit, lo, spacing, shape, level, sizes, band_width, disable):
    global _last_stats
    from skimage.measure._marching_cubes_lewiner_cy import remove_degenerate_faces

    plan = _coarse_pass(implicit, lo, spacing, shape, level, sizes, band_width, disable)
    if not plan.marked.any():
        raise InputError(
            f"f never crosses level {level} inside the bounds (values from {plan.vmin:.3g} to "
            f"{plan.vmax:.3g} on the coarse grid): widen `bounds` or check the fit"
        )
    layout = _layout(plan)
    vals, vmin, vmax = _evaluate_band(implicit, lo, spacing, plan, layout, disable)
    if not (vmin < level < vmax):
        raise InputError(
            f"f never crosses level {level} inside the bounds (values from {vmin:.3g} to "
            f"{vmax:.3g}): widen `bounds` or check the fit"
        )
    g32, faces, orient, bricks = _mesh_band(spacing, plan, layout, vals, level, disable)
    _last_stats = BandStats(
        shape=tuple(shape),
        cell=plan.c,
        gradient_samples=plan.gradient_samples,
        band_samples=int(layout.inband.sum()),
        band_cells=int(plan.marked.sum()),
        cells=int(np.prod(plan.nc)),
        bricks=bricks,
    )
    if not disable:
        s = _last_stats
        print(
            f"narrow band: {100 * s.fraction:.1f}% of {_human(s.grid_samples)} grid samples "
            f"evaluated ({_human(s.gradient_samples)} with gradients on coarse levels, "
            f"{_human(s.band_samples)} in the band; {s.bricks} bricks)",
            file=sys.stderr,
        )
    if len(faces) == 0:
        raise InputError(
            f"f never crosses level {level} inside the bounds (values from {vmin:.3g} to "
            f"{vmax:.3g}): widen `bounds` or check the fit"
        )
    # as marching cubes does with `spacing`: scale in double, round to float32, drop degenerate
    # faces (those with two vertices at one float32 point, whose vertices it merges)
    world = g32.astype(np.float64) * spacing
    world, faces = remove_degenerate_faces(world.astype(np.float32), faces.astype(np.int32))
    return world + lo, faces.astype(np.int64), orient


def marched(vol: np.ndarray, level: float, spacing, lo) -> tuple[np.ndarray, np.ndarray]:
    """Marching cubes of the sampled grid `vol` (spacing `spacing` per axis, first sample at
    `lo`) at `level`: vertices in world coordinates, and faces whose normals point up the
    gradient, out of the region below `level`."""
    from skimage.measure import marching_cubes

    verts, faces, normals, _ = marching_cubes(
        vol, level, spacing=tuple(np.broadcast_to(spacing, 3)), allow_degenerate=False
    )
    verts = verts + lo
    faces = faces.astype(np.int64)
    # marching_cubes' normals point down the gradient ('descent'); ours should point up it.
    tri = verts[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    if np.sum(fn * normals[faces].sum(axis=1)) > 0:
        faces = faces[:, ::-1].copy()
    return verts, faces


def polygonize(
    implicit: Callable,
    resolution: int | tuple[int, int, int] = 128,
    bounds=None,
    *,
    level: float = 0.0,
    project: bool = False,
    padding: float = 0.05,
    progress: bool | None = None,
    narrow_band: bool | None = None,
    coarsening: int = 8,
    band_width: float = 1.5,
    refine: int = 1,
    prune: bool | None = None,
):
    """Mesh the level set f = `level` of a 3-D implicit with marching cubes.

    **Arguments:**
    - `implicit`: an `RBFModel` or any JAX-traceable callable mapping (n, 3) points to (n,) values.
    - `resolution`: samples along the longest side of the box (cubic voxels), or one per axis.
    - `bounds`: `(lo, hi)`; default for a model: its centres' box grown by `padding` of its size.
    - `level`: the iso-value. `project`: Newton-project the vertices onto f = level with the
      analytic gradient (closer to the true surface than marching cubes' linear interpolation).
    - `progress`: progress bars on stderr, and for the narrow band one line with the share of the
      grid it evaluated (default: when stderr is a terminal).
    - `narrow_band`: evaluate f only near the surface, so that work and memory grow with the
      surface's area rather than the box's volume; the full grid is never allocated. Default
      (None): on when the grid has more than 160 samples along its longest side. With False, a
      grid that does not fit in the available memory is refused.
    - `coarsening`, `refine`, `band_width` (narrow band only): a coarse grid takes every
      `coarsening`-th fine sample per axis and evaluates f and its gradient (forward-mode JAX)
      there. A coarse cell may hold the surface when its corners lie on both sides of `level`,
      or when the distance estimate |f - level| / |grad f| at one of its corners is below
      `band_width` cell diagonals; those cells, grown by one cell on every side, form the band.
      `refine` times, the band's cells are halved and tested again (gradients inside the band
      only): 8 then 4 fine cells by default. The band's fine samples are then evaluated and
      marching cubes runs on bricks of 64^3 cells, the samples left out holding a value on the
      side the coarse test found. The mesh is the dense path's (same vertices, same faces) when
      the band holds every cell the surface crosses; a feature smaller than a coarse cell where f
      is far from a distance function can be missed: raise `band_width` or lower `coarsening`.
      `last_band_stats()` tells what was evaluated.

    - `prune`: drop mesh components that lie mostly away from the data (see
      `PartitionModel.coverage`: most of their vertices where the finest level's weights sum
      below `TAU`, i.e. a patch radius or more from every input sample). A partition of unity's coarse levels can cross zero there,
      in concave regions, and leave small floating pieces (fandisk at 100k points: 15 pieces,
      1,600 faces, up to 3% of the diagonal off the surface). Default (None): on for models that
      have `coverage` (partitions of unity), off otherwise; a line on stderr says what was dropped.

    **Returns:** a `jaxrbf.io.Mesh` (vertices in world coordinates, faces oriented outward: their
    normals point to increasing f).
    """
    from .io import Mesh

    _check_band_args(coarsening, refine, band_width)
    lo, hi = _bounds(implicit, bounds, 3, padding)
    spacing, shape = _grid_shape(lo, hi, resolution)
    if narrow_band is None:
        narrow_band = max(shape) > _AUTO_BAND
    if narrow_band:
        check_resolution(
            resolution, hi - lo, narrow_band=True, coarsening=coarsening, refine=refine
        )
        sizes = _sizes(int(coarsening), int(refine))
        disable = (not sys.stderr.isatty()) if progress is None else not progress
        verts, faces, orient = _polygonize_band(
            implicit, lo, spacing, shape, float(level), sizes, band_width, disable
        )
        if orient > 0:
            faces = faces[:, ::-1].copy()
    else:
        total = int(np.prod(shape))
        avail = _available_memory()
        if avail is not None and _DENSE_BYTES * total > avail:
            raise InputError(
                f"a dense {'x'.join(map(str, shape))} grid ({total:,} samples) needs about "
                f"{_DENSE_BYTES * total / 2**30:.1f} GiB but {avail / 2**30:.1f} GiB is "
                "available: use narrow_band=True (memory and work near the surface only) or a "
                "lower `resolution`"
            )
        vol, spacing = sample_grid(implicit, lo, hi, resolution, progress=progress, desc="meshing")
        if not (vol.min() < level < vol.max()):
            raise InputError(
                f"f never crosses level {level} inside the bounds (values from {vol.min():.3g} to "
                f"{vol.max():.3g}): widen `bounds` or check the fit"
            )
        verts, faces = marched(vol, level, spacing, lo)
    if prune is None:
        prune = hasattr(implicit, "coverage")
    if prune:
        quiet = (not sys.stderr.isatty()) if progress is None else not progress
        verts, faces = _prune(implicit, verts, faces, disable=quiet)
    if project:
        moved, ok = _project(implicit, verts, level=level, max_step=float(spacing.max()))
        verts = np.where(ok[:, None], moved, verts)
    return Mesh(verts, faces)


def _components(verts: np.ndarray, faces: np.ndarray) -> tuple[int, np.ndarray]:
    """The connected components of a mesh: their count and each vertex's label."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(verts)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]]])
    graph = coo_matrix((np.ones(len(edges), np.int8), (edges[:, 0], edges[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)


def _keep_components(verts: np.ndarray, faces: np.ndarray, label: np.ndarray, good: np.ndarray):
    """The mesh of the components marked `good` (by label): vertices re-indexed, faces."""
    keep_face = good[label[faces[:, 0]]]
    used = np.zeros(len(verts), bool)
    used[faces[keep_face].ravel()] = True
    new_index = np.cumsum(used) - 1
    return verts[used], new_index[faces[keep_face]]


def _prune(implicit, verts: np.ndarray, faces: np.ndarray, disable: bool):
    """Drop the connected components of the mesh most of whose vertices lie where the
    partition's finest level hands over to the coarse levels (`implicit.coverage` below the
    blend's `TAU`): a patch radius or more from every input sample, where only the coarse
    levels' extrapolation speaks. Returns the kept vertices (re-indexed) and faces."""
    from ._partition import TAU

    if not hasattr(implicit, "coverage"):
        raise InputError(
            "prune=True needs an implicit that knows where its data lies (a PartitionModel has "
            "`coverage`); this one has no `coverage` method"
        )
    if len(faces) == 0:
        return verts, faces
    n_comp, label = _components(verts, faces)
    near = np.asarray(implicit.coverage(verts)) >= TAU
    share = np.bincount(label, near, minlength=n_comp) / np.bincount(label, minlength=n_comp)
    good = share >= 0.5
    if good.all():
        return verts, faces
    verts_kept, faces_kept = _keep_components(verts, faces, label, good)
    if not disable:
        from ._constraints import log

        log(
            f"dropped {int((~good).sum())} of {n_comp} mesh components "
            f"({len(faces) - len(faces_kept):,} faces) lying mostly a patch radius or more from "
            "every input sample (prune=False keeps them)"
        )
    return verts_kept, faces_kept


#: A mesh component with no input sample within this many of the samples' point spacings of
#: any of its vertices accounts for no input (`drop_unsupported`) ...
SUPPORT_SPACINGS = 2.0
#: ... nor does one that fewer than this many distinct samples are nearest to: a bubble round
#: a stray point (10k samples of the bunny with 100 strays in its box, 30 of them within a few
#: spacings of the surface after `jaxrbf._clean.isolated`: 8 such bubbles of 34-354 vertices,
#: one sample each).
SUPPORT_MIN = 3


def drop_unsupported(
    mesh, samples: np.ndarray, spacing: float, cell: float = 0.0, verbose: bool = False
):
    """`mesh` without its connected components that lie wholly away from the `samples` (fewer
    than `SUPPORT_MIN` distinct samples nearest to its vertices within `SUPPORT_SPACINGS` x
    `spacing`, or within a diagonal of the meshing grid's `cell`, which a surface through a
    sample may leave between it and its nearest vertex): a surface with no input behind it (the
    small closed bubbles a fit can leave between the samples and the volume constraints that
    say outside there, or round a stray sample). The mesh is
    returned as it is when no component has a sample near (the accounts check then says what is
    wrong)."""
    from scipy.spatial import cKDTree

    from .io import Mesh

    verts, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    if len(faces) == 0 or len(samples) == 0:
        return mesh
    n_comp, label = _components(verts, faces)
    if n_comp == 1:
        return mesh
    reach = max(SUPPORT_SPACINGS * spacing, math.sqrt(3.0) * cell)
    d, near = cKDTree(samples).query(verts, distance_upper_bound=reach, workers=-1)
    surface = np.bincount(label[faces[:, 0]], minlength=n_comp) > 0  # not a loose vertex
    # the distinct samples nearest to each component's vertices: a bubble grown round one or two
    # samples alone (a stray point a few spacings off the surface) accounts for no surface
    ok = np.isfinite(d)
    pairs = np.unique(np.stack([label[ok], near[ok]], axis=1), axis=0)
    support = np.bincount(pairs[:, 0], minlength=n_comp)
    unsupported = surface & (support < SUPPORT_MIN)
    if not unsupported.any() or unsupported.sum() == surface.sum():
        return mesh
    verts_kept, faces_kept = _keep_components(verts, faces, label, ~unsupported)
    if verbose:
        from ._constraints import log

        log(
            f"dropped {int(unsupported.sum())} of {int(surface.sum())} mesh components "
            f"({len(faces) - len(faces_kept):,} faces) with fewer than {SUPPORT_MIN} input "
            f"samples within {reach / spacing:.2g} point spacings of them"
        )
    return Mesh(verts_kept, faces_kept)


def contour(
    implicit: Callable,
    resolution: int | tuple[int, int] = 256,
    bounds=None,
    *,
    level: float = 0.0,
    padding: float = 0.05,
    progress: bool | None = None,
) -> list[np.ndarray]:
    """Curves of f = `level` of a 2-D implicit (marching squares, `skimage.measure.find_contours`).

    **Arguments:** as for `polygonize`, for (n, 2) points.

    **Returns:** a list of (k, 2) arrays in world coordinates; a closed curve repeats its first
    vertex at the end.
    """
    from skimage.measure import find_contours

    lo, hi = _bounds(implicit, bounds, 2, padding)
    check_resolution(resolution, hi - lo, narrow_band=False)
    grid, spacing = sample_grid(implicit, lo, hi, resolution, progress=progress, desc="contouring")
    return [lo + c * spacing for c in find_contours(grid, level)]
