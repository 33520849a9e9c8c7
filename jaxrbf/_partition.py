"""Partition-of-unity RBF models for large inputs (Ohtake et al. 2003; Wendland 2005, ch. 15).

The normalised domain is split into overlapping spherical patches; each patch gets its own small
RBF fit (the dense saddle system of eq. 6 on the constraints inside it), and the local fits are
blended with smooth, compactly supported weights:

    f(x) = (sum_i psi_i(x) f_i(x) + w_0(x) g(x)) / (sum_i psi_i(x) + w_0(x))

- **Patches**: a k-d split of the constraints into leaves of at most `leaf` points; patch i is the
  ball around leaf i's bounding box, radius R_i = `alpha` x its half-diagonal, grown until it holds
  `min_points` constraints. Its local fit uses the constraints in the ball (at most `max_points`,
  the nearest to its centre). Every constraint lies in its leaf's box, so the balls cover every
  constraint with room to spare.
- **Weights**: psi_i(x) = phi_W(|x - o_i| / R_i) with Wendland's C2 function
  phi_W(t) = (1 - t)_+^4 (4 t + 1). Each f_i is smooth and each psi_i is C2, so f and its gradient
  are continuous everywhere, across patch borders included.
- **Fallback**: away from the data no patch covers x. There the blend hands over to a coarser model
  g (the same construction on a 1/8 subsample of the constraints, down to a global fit of a few
  thousand), through w_0 = tau (1 - W / tau)_+^2 with W = sum_i psi_i: w_0 = 0 where the patches
  cover x well (W >= tau), and f = g where none does. w_0 is C1 in W, so f stays C1. g is only
  evaluated for blocks of points that need it.
- **Evaluation** touches only the patches that cover a point: a uniform grid of cells lists, for
  each cell, the patches whose balls meet it (padded to a common length with a dummy patch of zero
  weight), so a block of points gathers its K candidate patches and evaluates K x m kernel values
  per point, whatever the total number of patches.

Precision: local solves and evaluation in float64, like the dense path (local systems of a few
hundred cubic-kernel constraints are as badly conditioned as a global one of the same density).

The local fits run as one jit-compiled function over fixed-size batches of padded patches (vmap
over patches, masks for the padding), so a million points compile once; with several JAX devices
each batch is sharded over them (see `jaxrbf._sharding`).
"""

from __future__ import annotations

import time
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, Float, Int
from scipy.spatial import cKDTree

from ._constraints import VOLUME_SMOOTHING, log, progress_bar
from ._errors import InputError, SolveError
from ._model import AbstractModel, _traced, kernel_block, poly_basis
from ._schwarz import _kd_leaves
from .kernels import AbstractKernel, _safe_sqrt
from .objectives import point_spacing

#: Constraints per k-d leaf. A patch's ball then holds about 4-5x as many (it reaches into the
#: neighbouring leaves), which is what the local solve costs: O(m^3) per patch.
LEAF = 24
#: Patch radius as a multiple of its leaf box's half-diagonal: the overlap between patches.
#: 1.5 is MPU's (Ohtake et al. 2003: 0.75 of the cell's diagonal). At 1.25, where random
#: samples leave a gap a few spacings wide, a point in it sat at the rims of two or three
#: patches (weights 0.1 or less), each extrapolating its own side, and the blend bulged out by
#: two offsets (fandisk, 10k samples: the surface 0.9% of the diagonal off the true one; at
#: 1.5, precision at 0.5% 99.89% -> 99.92% and NC 0.9826 -> 0.9839, and NC rose on the cow,
#: the bunny, suzanne and the teapot too, for about 10% more time).
ALPHA = 1.5
#: The same for a smoothed fit (smoothing > 0: a noisy cloud, approximated). Its samples are
#: dense and it passes through none of them, so no patch overshoots at its rim; and 1.5 split
#: more balls past `MAX_POINTS` there (the real leg scan: 7,943 -> 10,996 patches, meshing 38 ->
#: 60 s) and lost precision at 0.5% on two of six virtual range scans (teapot 99.22% -> 99.06%,
#: cow with scanner normals 99.91% -> 99.87%; NC rose by 0.002 on all six).
ALPHA_SMOOTHED = 1.25
MIN_POINTS = 48
MAX_POINTS = 128
#: Below this total weight of the patches, the coarser fallback model takes over (see above).
TAU = 0.005
#: Each coarser level keeps one constraint in this many.
COARSENING = 8
#: Off-surface offset of the coarser levels, in their own median point spacings.
COARSE_OFFSET_SPACINGS = 2.0
#: A coarse level is rebuilt from the surface (see `fit_partition`) when it keeps at least this
#: many surface points; a sparser one is a random subsample of the finer level's constraints,
#: which covers more places (measured on a 960-point torus: the rebuilt levels left sign errors
#: away from the data that the subsample does not).
COARSE_SURFACE_MIN = 1000
#: A level of at most this many constraints is a single global fit.
BASE_SIZE = 3000
#: Volume constraints that no finer level's patches hold make leaves of about this many at the
#: last level above the base, apart from the surface's leaves.
ORPHAN_LEAF = 6
#: Patches solved per compiled batch.
BATCH = 256
#: At most this many cells in the evaluation lookup grid.
MAX_CELLS = 2**24


def wendland_weight(t2: Array) -> Array:
    """Wendland's C2 function (1 - t)_+^4 (4 t + 1) of t = sqrt(t2), with a finite gradient at 0."""
    t = _safe_sqrt(t2)
    return jnp.where(t < 1.0, (1.0 - t) ** 4 * (4.0 * t + 1.0), 0.0)


class PartitionModel(AbstractModel):
    """A partition-of-unity blend of local RBF fits (see the module docstring).

    Called like an `RBFModel`: points in the user's units, values, `gradient`, `normal`,
    `bounds`; `polygonize`, `project`, the metrics and `save`/`load` accept it.

    **Fields** (patch arrays have one extra, dummy row of zero weight, used for padding):
    - `origin` (P + 1, d), `radius` (P + 1,): the patches' balls, normalised units.
    - `centres` (P + 1, m, d), `weights` (P + 1, m): each patch's RBF centres (padded with
      weight 0) and weights. `coeffs` (P + 1, k): its polynomial in (x - o_i) / R_i.
    - `cell_row` (C,), `table` (rows, K), `grid_lo` (d,), `cell_size`, `grid_dims`: the lookup
      grid: cell -> row of `table` -> K candidate patches.
    - `kernel`, `degree`: as in `RBFModel`.
    - `background`: the coarser model used where no patch covers a point.
    - `shift`, `scale`: the normalising transform; `residual`: max |f - h| / max |h| over the
      constraints (or a sample of them).
    """

    origin: Float[Array, "P d"]
    radius: Float[Array, " P"]
    centres: Float[Array, "P m d"]
    weights: Float[Array, "P m"]
    coeffs: Float[Array, "P k"]
    cell_row: Int[Array, " C"]
    table: Int[Array, "R K"]
    grid_lo: Float[Array, " d"]
    cell_size: Float[Array, ""]
    kernel: AbstractKernel
    background: AbstractModel
    shift: Float[Array, " d"]
    scale: Float[Array, ""]
    residual: Float[Array, ""]
    degree: int = eqx.field(static=True)
    grid_dims: tuple[int, ...] = eqx.field(static=True)

    @property
    def n_patches(self) -> int:
        return int(self.origin.shape[0]) - 1

    @property
    def n_levels(self) -> int:
        bg = self.background
        return 1 + (bg.n_levels if isinstance(bg, PartitionModel) else 1)

    def _block_rows(self) -> int:
        per_point = self.table.shape[1] * self.centres.shape[1]
        rows = max(8, min(1024, 2**18 // max(per_point, 1)))
        return 1 << (rows.bit_length() - 1)

    def bounds(self) -> tuple[Array, Array]:
        """Bounding box (lo, hi) of the patch centres' RBF centres, in the user's coordinates."""
        real = self.centres[:-1].reshape(-1, self.dim)
        world = real * self.scale + self.shift
        return world.min(axis=0), world.max(axis=0)

    def _candidates(self, xn: Array) -> Array:
        dims = jnp.asarray(self.grid_dims)
        cell = jnp.floor((xn - self.grid_lo) / self.cell_size).astype(jnp.int32)
        cell = jnp.clip(cell, 0, dims - 1)
        flat = cell[:, 0]
        for k in range(1, self.dim):
            flat = flat * self.grid_dims[k] + cell[:, k]
        return self.table[self.cell_row[flat]]

    def blend(self, xn: Float[Array, "b d"]) -> tuple[Array, Array]:
        """(sum_i psi_i f_i, sum_i psi_i) at normalised points: the patches' part of the blend."""
        pids = self._candidates(xn)  # (b, K)
        o, r = self.origin[pids], self.radius[pids]
        diff = xn[:, None, :] - o  # (b, K, d)
        psi = wendland_weight(jnp.sum(diff * diff, axis=-1) / (r * r))
        c = self.centres[pids]  # (b, K, m, d)
        r2 = jnp.zeros(c.shape[:-1], dtype=xn.dtype)
        for k in range(self.dim):
            r2 = r2 + (xn[:, None, None, k] - c[..., k]) ** 2
        local = jnp.einsum("bkm,bkm->bk", self.kernel.from_r2(r2), self.weights[pids])
        b, kk = pids.shape
        poly = poly_basis((diff / r[..., None]).reshape(b * kk, self.dim), self.degree)
        local = local + jnp.einsum("bkj,bkj->bk", poly.reshape(b, kk, -1), self.coeffs[pids])
        return jnp.sum(psi * local, axis=1), jnp.sum(psi, axis=1)

    def evaluate_many(self, points, grad: bool = False):
        """f and (with `grad`) grad f at many concrete points (n, d), as numpy arrays: the same
        values as calling the model, computed patch by patch (see `evaluate_many` in this
        module); `polygonize` uses it for grids and bands."""
        return evaluate_many(self, points, grad)

    def coverage(self, points) -> np.ndarray:
        """The finest level's weight sum, sum_i psi_i, at concrete points (n, d), on the host
        (no kernel evaluation). Near the input samples it is of order 1; where it falls below
        `TAU` the blend hands over to the coarser levels, which alone define f a patch radius or
        more from every sample. `polygonize` drops mesh components lying mostly there."""
        xn = (np.asarray(points, dtype=float) - np.asarray(self.shift)) / float(self.scale)
        host = _host(self)
        out = np.zeros(len(xn))
        for s0 in range(0, len(xn), 2**16):
            part = xn[s0 : s0 + 2**16]
            pt, patch = _covering(host, self.grid_dims, part)
            ball = host.balls[patch]
            t2 = np.sum((part[pt] - ball[:, :-1]) ** 2, axis=1) / ball[:, -1]
            psi = np.asarray(wendland_weight(jnp.asarray(t2)))
            out[s0 : s0 + len(part)] = np.bincount(pt, psi, minlength=len(part))
        return out

    def __call__(self, x):
        flat, lead = self._flat(x)
        if len(flat) >= BULK_MIN and not _traced(self, flat):
            return jnp.asarray(evaluate_many(self, np.asarray(flat))[0]).reshape(lead)
        return super().__call__(x)

    def value_and_gradient(self, x):
        flat, lead = self._flat(x)
        if len(flat) >= BULK_MIN and not _traced(self, flat):
            f, g = evaluate_many(self, np.asarray(flat), True)
            return jnp.asarray(f).reshape(lead), jnp.asarray(g).reshape(lead + (self.dim,))
        return super().value_and_gradient(x)

    def _eval_normalised(self, xn: Float[Array, "b d"]) -> Float[Array, " b"]:
        num, den = self.blend(xn)
        short = jnp.maximum(1.0 - den / TAU, 0.0)
        w0 = TAU * short * short
        bg = self.background

        def fallback(y):
            world = y * self.scale + self.shift
            return bg._eval_normalised(bg.normalise(world))

        g = lax.cond(jnp.any(w0 > 0), fallback, lambda y: jnp.zeros(y.shape[:1], y.dtype), xn)
        return (num + w0 * g) / (den + w0)


# --- construction (host) -----------------------------------------------------------------------


class Patches(NamedTuple):
    """Host-side patch layout: balls and their members (indices into the constraints)."""

    origin: np.ndarray  # (P, d)
    radius: np.ndarray  # (P,)
    members: np.ndarray  # (P, m) int, padded with n
    mask: np.ndarray  # (P, m) bool


def _balls(x: np.ndarray, leaves: list[np.ndarray], alpha: float):
    lengths = np.array([len(lf) for lf in leaves])
    size = int(lengths.max())
    flat = np.concatenate(leaves)
    starts = np.cumsum(lengths) - lengths
    # (P, size) member indices, each leaf padded by repeating its last member
    cols = np.minimum(np.arange(size)[None, :], lengths[:, None] - 1)
    pts = x[flat[starts[:, None] + cols]]  # (P, size, d)
    origin = 0.5 * (pts.min(axis=1) + pts.max(axis=1))
    reach = np.sqrt(np.max(np.sum((pts - origin[:, None]) ** 2, axis=2), axis=1))
    return origin, alpha * np.maximum(reach, 1e-12)


def make_patches(
    x: np.ndarray,
    leaf: int = LEAF,
    alpha: float = ALPHA,
    min_points: int = MIN_POINTS,
    max_points: int = MAX_POINTS,
    lead: int | None = None,
    apart: int = 0,
    apart_leaf: int = 1,
) -> Patches:
    """The patches of normalised constraint points `x` (n, d); see the module docstring.

    Patch i is centred on leaf i's box; its radius is `alpha` x the distance from there to the
    leaf's farthest point (so every leaf point sits at t <= 1 / alpha, where its own weight is at
    least phi_W(1 / alpha)), grown to reach at least `min_points` constraints. Its fit takes every
    constraint in the ball; a leaf whose ball would hold more than `max_points` (where sheets of
    the surface come close, or the leaf is elongated) is split in two until none does, so every
    local fit interpolates every constraint its weight reaches.

    Only the first `lead` points (default: all) make leaves; the others (volume constraints
    away from the surface) join the fits of the patches whose balls hold them. The last `apart`
    of the lead points make leaves of their own, of about `apart_leaf` points each."""

    n, _ = x.shape
    lead = n if lead is None else lead
    tree = cKDTree(x)
    grouped = lead - apart
    leaves = _kd_leaves(x, np.arange(grouped), max(1, -(-grouped // leaf))) if grouped else []
    if apart:
        leaves += _kd_leaves(x, np.arange(grouped, lead), max(1, -(-apart // apart_leaf)))
    for _ in range(30):
        origin, radius = _balls(x, leaves, alpha)
        count = tree.query_ball_point(origin, radius, return_length=True, workers=-1)
        # Down to single points: a leaf of two (a stray point and its nearest neighbour in a
        # crowd) whose ball is cut to `max_points` below can leave both near the cut ball's rim,
        # where every patch's weight is below TAU and the coarser level, which does not hold
        # them, takes over; a single point is its ball's centre, at weight 1.
        split = (count > max_points) & np.array([len(lf) > 1 for lf in leaves])
        if not split.any():
            break
        leaves = [lf for lf, s in zip(leaves, split, strict=True) if not s] + [
            half for lf, s in zip(leaves, split, strict=True) if s for half in _kd_leaves(x, lf, 2)
        ]
    k = min(min_points, n)
    dist, _ = tree.query(origin, k=k, workers=-1)
    radius = np.maximum(radius, dist.reshape(len(origin), k)[:, -1] * (1 + 1e-9))
    # Bounded whatever the geometry (a leaf of two points can still see a crowd): the m nearest.
    m = min(int(tree.query_ball_point(origin, radius, return_length=True, workers=-1).max()), n)
    m = min(m, max_points)
    dist, idx = tree.query(origin, k=m, workers=-1)
    dist, idx = dist.reshape(len(origin), m), idx.reshape(len(origin), m)
    radius = np.minimum(radius, np.maximum(dist[:, -1], 1e-12))
    mask = dist <= radius[:, None]
    idx = np.where(mask, idx, n)
    # Patches sorted by size, so that batches of neighbours in this order pad little.
    order = np.argsort(mask.sum(axis=1), kind="stable")
    return Patches(origin[order], radius[order], idx[order], mask[order])


def lookup_grid(origin: np.ndarray, radius: np.ndarray, cell_factor: float = 0.5):
    """Cells -> candidate patches: (grid_lo, cell_size, dims, cell_row, table). `table` row 0 is
    empty (only the dummy patch, index P); every cell that some ball meets has its own row."""
    n_p, dim = origin.shape
    glo = (origin - radius[:, None]).min(axis=0)
    ghi = (origin + radius[:, None]).max(axis=0)
    cs = max(float(np.median(radius)) * cell_factor, 1e-12)
    while True:
        dims = np.maximum(np.ceil((ghi - glo) / cs).astype(np.int64), 1)
        if np.prod(dims) <= MAX_CELLS:
            break
        cs *= 1.25
    i0 = np.clip(np.floor((origin - radius[:, None] - glo) / cs).astype(np.int64), 0, dims - 1)
    i1 = np.clip(np.floor((origin + radius[:, None] - glo) / cs).astype(np.int64), 0, dims - 1)
    ext = i1 - i0 + 1
    counts = np.prod(ext, axis=1)
    pid = np.repeat(np.arange(n_p), counts)
    local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    cell = np.empty((len(pid), dim), dtype=np.int64)
    for k in range(dim - 1, -1, -1):
        e = ext[pid, k]
        cell[:, k] = i0[pid, k] + local % e
        local = local // e
    box_lo = glo + cell * cs
    nearest = np.clip(origin[pid], box_lo, box_lo + cs)
    keep = np.sum((nearest - origin[pid]) ** 2, axis=1) <= radius[pid] ** 2
    pid, cell = pid[keep], cell[keep]
    flat = np.ravel_multi_index(cell.T, dims)
    order = np.argsort(flat, kind="stable")
    flat, pid = flat[order], pid[order]
    cells, start, per = np.unique(flat, return_index=True, return_counts=True)
    k_max = int(per.max())
    table = np.full((len(cells) + 1, k_max), n_p, dtype=np.int32)
    row_of = np.repeat(np.arange(len(cells)), per)
    col = np.arange(len(flat)) - np.repeat(start, per)
    table[row_of + 1, col] = pid
    cell_row = np.zeros(int(np.prod(dims)), dtype=np.int32)
    cell_row[cells] = np.arange(1, len(cells) + 1, dtype=np.int32)
    return glo, cs, tuple(int(d) for d in dims), cell_row, table


def _flat(cov: Array) -> Array:
    """Whether the points of covariance `cov` (d, d) are (nearly) coplanar or collinear: det(cov)
    below 1e-10 (trace / d)^d, i.e. the smallest eigenvalue below about 1e-10 of the others.
    Closed forms in 2-D and 3-D (an eigensolver would double the batch's compile time)."""
    d = cov.shape[0]
    tr = jnp.maximum(jnp.trace(cov) / d, 1e-300)
    if d == 2:
        det = cov[0, 0] * cov[1, 1] - cov[0, 1] * cov[1, 0]
    elif d == 3:
        det = (
            cov[0, 0] * (cov[1, 1] * cov[2, 2] - cov[1, 2] * cov[2, 1])
            - cov[0, 1] * (cov[1, 0] * cov[2, 2] - cov[1, 2] * cov[2, 0])
            + cov[0, 2] * (cov[1, 0] * cov[2, 1] - cov[1, 1] * cov[2, 0])
        )
    else:
        ev = jnp.linalg.eigvalsh(cov)
        return ev[0] <= 1e-10 * jnp.maximum(ev[-1], 1e-300)
    return det <= 1e-10 * tr**d


@eqx.filter_jit
def _fit_batch(kernel, xs, hs, mask, origin, radius, degree: int, smoothing, row_scale=None):
    """Local saddle-system solves for a batch of padded patches (vmap). Returns weights, coeffs
    and each patch's relative residual on its own constraints. `row_scale` (the shape of `hs`,
    default all 1) scales `smoothing` row by row: the term added to each row's diagonal."""

    def one(x, h, keep, o, r, rs):
        m = x.shape[0]
        both = keep[:, None] & keep[None, :]
        a = kernel_block(kernel, x, x) + jnp.diag(smoothing * rs).astype(x.dtype)
        # Equilibrate: kernel entries of a small patch are tiny next to the polynomial's.
        s = 1.0 / jnp.maximum(jnp.max(jnp.where(both, jnp.abs(a), 0.0)), 1e-300)
        a_s = jnp.where(both, a * s, 0.0) + jnp.diag(~keep).astype(x.dtype)
        local = (x - o) / r
        p = poly_basis(local, degree) * keep[:, None]
        k = p.shape[1]
        # A patch whose points are (nearly) coplanar cannot fix the linear terms: drop them there.
        if k > 1:
            w = keep.astype(x.dtype)[:, None]
            mean = jnp.sum(local * w, axis=0) / jnp.maximum(jnp.sum(w), 1.0)
            cov = ((local - mean) * w).T @ ((local - mean) * w)
            flat = _flat(cov)
            cols = jnp.concatenate([jnp.array([True]), jnp.full((k - 1,), ~flat)])
            p = p * cols[None, :]
            corner = jnp.diag(~cols).astype(x.dtype)
        else:
            corner = jnp.zeros((k, k), x.dtype)
        hk = jnp.where(keep, h, 0.0)
        if k:
            big = jnp.block([[a_s, p], [p.T, corner]])
            sol = jnp.linalg.solve(big, jnp.concatenate([hk, jnp.zeros((k,), x.dtype)]))
            wts, cf = sol[:m] * s * keep, sol[m:]
        else:
            wts, cf = jnp.linalg.solve(a_s, hk) * s * keep, jnp.zeros((0,), x.dtype)
        fit = jnp.where(both, a, 0.0) @ wts + p @ cf
        err = jnp.max(jnp.where(keep, jnp.abs(fit - hk), 0.0))
        rel = err / jnp.maximum(jnp.max(jnp.abs(hk)), 1e-300)
        return wts, cf, rel

    rows = jnp.ones_like(hs) if row_scale is None else row_scale
    return jax.vmap(one)(xs, hs, mask, origin, radius, rows)


def fit_patches(
    kernel,
    xn,
    h,
    degree,
    smoothing,
    patches: Patches,
    *,
    row_scale=None,
    verbose=False,
    desc="patches",
):
    """Solve every patch's local system, in fixed-size batches. Returns (weights, coeffs,
    worst local residual), the arrays with the dummy row appended. `row_scale` (one per
    constraint, default all 1) scales `smoothing` constraint by constraint."""
    from ._sharding import pad_to_devices, split_over_devices

    n_p, m = patches.members.shape
    dim = xn.shape[1]
    xpad = np.concatenate([xn, np.zeros((1, dim))])
    hpad = np.concatenate([h, np.zeros(1)])
    spad = np.concatenate([np.ones(len(h)) if row_scale is None else row_scale, np.ones(1)])
    k = poly_basis(jnp.zeros((1, dim)), degree).shape[1]
    weights = np.zeros((n_p + 1, m))
    coeffs = np.zeros((n_p + 1, k))
    worst = 0.0
    # one batch size for every level (a level with fewer patches is padded): fewer compilations
    batch = pad_to_devices(BATCH)
    with progress_bar(n_p, desc, "patch", True if verbose else None) as bar:
        for start in range(0, n_p, batch):
            sel = np.arange(start, start + batch)
            real = sel < n_p
            sel = np.where(real, sel, 0)
            # Pad this batch only to its own largest patch (rounded up: few distinct shapes,
            # so few compilations); patches come sorted by size.
            width = min(m, -(-int(patches.mask[sel].sum(axis=1).max()) // 32) * 32)
            mem = patches.members[sel, :width]
            mask = patches.mask[sel, :width] & real[:, None]
            args = (xpad[mem], hpad[mem], mask, patches.origin[sel], patches.radius[sel], spad[mem])
            w, c, rel = split_over_devices(
                lambda *a: _fit_batch(kernel, *a[:5], degree, smoothing, a[5]), *args
            )
            w, c, rel = np.asarray(w), np.asarray(c), np.asarray(rel)
            stop = min(start + batch, n_p)
            weights[start:stop, :width], coeffs[start:stop] = w[: stop - start], c[: stop - start]
            bad = ~np.isfinite(rel[real]) | ~np.all(np.isfinite(w[real]), axis=1)
            if bad.any():
                raise SolveError(
                    f"{int(bad.sum())} local fits (patches near index {start}) produced NaN: their "
                    "points are degenerate; try smoothing > 0"
                )
            worst = max(worst, float(rel[real].max()))
            bar.update(stop - start)
    return weights, coeffs, worst


def fit_partition(
    xw: np.ndarray,
    h: np.ndarray,
    *,
    kernel: AbstractKernel,
    degree: int,
    smoothing: float,
    shift: np.ndarray,
    scale: float,
    leaf: int | None = None,
    base_size: int | None = None,
    seed: int = 0,
    verbose: bool = False,
    level: int = 0,
    surface: tuple[np.ndarray, np.ndarray] | None = None,
    n_volume: int = 0,
    volume: tuple[np.ndarray, np.ndarray] | None = None,
    orphans: np.ndarray | None = None,
):
    """The partition-of-unity model of constraints `xw` with values `h`, both in the user's units
    (as are `kernel`'s radius and `smoothing`); `shift` and `scale` map them into the unit box.

    Recursive: the fallback is the same construction on a 1/`COARSENING` subsample, down to
    `BASE_SIZE` constraints, which get one global fit (`jaxrbf.fit`).

    Coarser levels of surface constraints (on-surface points with value 0 and off-surface points
    along their normals, as `Constraints.from_points` builds them) are rebuilt from a subsample
    of the surface points (`surface`: points and normals, recovered from the constraints at the
    top) with an offset of `COARSE_OFFSET_SPACINGS` of that level's own point spacing: the fine level's small offset, kept on a sparse subsample,
    leaves a fallback whose zero set strays far from the data (measured: spurious sheets 3% of
    the diagonal away on the fandisk). Other constraints are subsampled as they are.

    The last `n_volume` constraints are volume constraints (`volume` below the top: points and
    signed distances to the surface): each level takes those between `VOLUME_NEAR` and
    `VOLUME_FAR` of its own point spacings from the surface, which its patches reach and its
    finer levels do not, into the fits of the patches that hold them (they make no patches);
    the last level above the base takes every one beyond, however far, and the global base
    level every one beyond `VOLUME_NEAR` spacings (at most `BASE_VOLUME`), so that far from the
    data f has the sign they give. A level's volume
    constraints where its patches' weights sum below `TAU` (where its fallback speaks) are
    handed down with the finer levels' (`orphans`: indices into `volume`) to each coarser level
    in turn, and the last level above the base makes patches of its own on those its surface
    patches do not hold either, from leaves of `ORPHAN_LEAF` of them apart from the surface's
    leaves (mixed into those, a probe lay at its patch's rim, at weight 0.0067, and half a
    probe spacing away the fallback spoke: on a virtual scan of the spot, bubbles inside its
    hooves and 28 stray components of 10,000 faces, where now 3 of 336 faces are left). Before, inside a thin part (the leg of a scanned cow, a tenth of
    the diagonal across) the probes lay in no level's patches, the base held a random few of
    them, and its global cubic gave the leg's core the wrong sign: a bubble of surface inside
    the leg, up to 5% of the diagonal from the true surface."""
    from ._fit import fit

    leaf = LEAF if leaf is None else leaf
    base_size = BASE_SIZE if base_size is None else base_size
    if n_volume:
        volume = (xw[-n_volume:], h[-n_volume:])
        xw, h = xw[:-n_volume], h[:-n_volume]
    n = len(xw)
    t0 = time.perf_counter()
    if n <= base_size:
        take = _level_volume(volume, xw, h, base=True, seed=seed + level, orphans=orphans)
        if len(take):
            xw, h = np.concatenate([xw, volume[0][take]]), np.concatenate([h, volume[1][take]])
        n = len(xw)
        # The coarsest fallback only has to give the right sign away from the data, so it is
        # always the robust polyharmonic fit (r^3 in 3-D, r^2 log r in 2-D; LU, which compiles in a
        # third of the time CG takes at this size), whatever the
        # patches use: a Gaussian base would be as ill-conditioned as a dense Gaussian fit.
        base_kernel = "cubic" if xw.shape[1] == 3 else "thin-plate"
        # `smoothing` is in the units of the patches' kernel (lambda scales as length^h): the
        # same relative smoothing for the base's kernel, of homogeneity 3 (cubic) or 2. Taken as
        # it is, a linear kernel's lambda is orders of magnitude too strong for r^3, and the
        # base flattens into its linear polynomial, with the wrong sign over half the box.
        base_h = 3 if xw.shape[1] == 3 else 2
        base_smoothing = smoothing / scale**kernel.homogeneity * scale**base_h
        base = fit(
            xw,
            h,
            kernel=base_kernel,
            degree=1,
            smoothing=base_smoothing,
            solver="lu",
            method="dense",
        )
        if verbose:
            log(
                f"level {level}: global {base_kernel} fit of {n:,} constraints in "
                f"{time.perf_counter() - t0:.1f} s (fallback far from the data)"
            )
        return base
    rng = np.random.default_rng(seed + level)
    if level == 0 and surface is None:
        surface = surface_of(xw, h)
    keep = 0 if surface is None else max(base_size // 6, len(surface[0]) // COARSENING)
    if keep >= COARSE_SURFACE_MIN:
        ps, ns = surface
        pick = np.sort(rng.choice(len(ps), min(keep, len(ps)), replace=False))
        coarse_surface = (ps[pick], ns[pick])
        xc, hc = coarse_constraints(*coarse_surface, between=not smoothing)
    else:
        sub = np.sort(rng.choice(n, max(base_size // 2, n // COARSENING), replace=False))
        coarse_surface, xc, hc = None, xw[sub], h[sub]
    # this level's patches first: the volume constraints they leave to the fallback go down
    last = len(xc) <= base_size  # the last level above the global base
    reach = VOLUME_FAR_FINEST if level == 0 else VOLUME_FAR
    take = _level_volume(
        volume, xw, h, base=False, seed=seed + level, orphans=orphans, last=last, reach=reach
    )
    lead = n
    if len(take):
        xw, h = np.concatenate([xw, volume[0][take]]), np.concatenate([h, volume[1][take]])
    probe = np.arange(len(xw)) >= n  # this level's volume constraints
    xn = (xw - shift) / scale
    alpha = ALPHA_SMOOTHED if smoothing else ALPHA
    patches = make_patches(xn, leaf=leaf, alpha=alpha, lead=lead)
    uncovered = coverage_at(patches.origin, patches.radius, xn[lead:]) < TAU
    left = take[uncovered]
    if len(left) and (last or level == 0):
        # what no level's patches hold makes patches of its own here (moved up to lead), so
        # that the base's global fit speaks only beyond every volume constraint; and at the
        # finest level, so that it holds the shell of probes off the samples (see
        # `VOLUME_FAR_FINEST`)
        order = np.concatenate(
            [np.arange(lead), lead + np.flatnonzero(uncovered), lead + np.flatnonzero(~uncovered)]
        )
        xw, h, xn, probe = xw[order], h[order], xn[order], probe[order]
        lead += len(left)
        patches = make_patches(
            xn, leaf=leaf, alpha=alpha, lead=lead, apart=len(left), apart_leaf=ORPHAN_LEAF
        )
        left = left[:0]
    background = fit_partition(
        xc,
        hc,
        kernel=kernel,
        degree=degree,
        smoothing=smoothing,
        shift=shift,
        scale=scale,
        leaf=leaf,
        base_size=base_size,
        seed=seed,
        verbose=verbose,
        level=level + 1,
        surface=coarse_surface,
        volume=volume,
        orphans=left,
    )
    t0 = time.perf_counter()
    kn = kernel.scaled(1.0 / scale)
    weights, coeffs, worst = fit_patches(
        kn,
        xn,
        h,
        degree,
        smoothing / scale**kernel.homogeneity,
        patches,
        row_scale=np.where(probe, VOLUME_SMOOTHING, 1.0),  # volume constraints held
        verbose=verbose,
        desc=f"level {level} patches",
    )
    glo, cs, dims, cell_row, table = lookup_grid(patches.origin, patches.radius)
    dim = xn.shape[1]
    n_p, m = patches.members.shape
    centres = np.concatenate([xn, np.zeros((1, dim))])[patches.members]
    centres = np.concatenate([centres, np.zeros((1, m, dim))])
    origin = np.concatenate([patches.origin, np.full((1, dim), 1e6)])
    rad = np.concatenate([patches.radius, [1.0]])
    model = PartitionModel(
        origin=jnp.asarray(origin),
        radius=jnp.asarray(rad),
        centres=jnp.asarray(centres),
        weights=jnp.asarray(weights),
        coeffs=jnp.asarray(coeffs),
        cell_row=jnp.asarray(cell_row),
        table=jnp.asarray(table),
        grid_lo=jnp.asarray(glo),
        cell_size=jnp.asarray(cs),
        kernel=kn,
        background=background,
        shift=jnp.asarray(shift, dtype=float),
        scale=jnp.asarray(scale, dtype=float),
        residual=jnp.asarray(worst),
        degree=degree,
        grid_dims=dims,
    )
    if verbose:
        log(
            f"level {level}: {n_p:,} patches of <= {m} constraints (lookup: {table.shape[1]} "
            f"candidates per cell) fitted in {time.perf_counter() - t0:.1f} s; worst local "
            f"residual {worst:.1e}"
        )
    return model


#: Each level takes the volume constraints between these many of its point spacings from the
#: surface: nearer ones its finer levels cover, farther ones its patches do not reach.
VOLUME_NEAR = 1.0
VOLUME_FAR = 4.0
#: The finest level takes them out to this many of its spacings, the shell of probes 4.5
#: spacings off the samples (`jaxrbf._winding.shell_probes`) included, and those its surface
#: patches do not hold make patches of their own (as at the last level above the base): its
#: patches then reach past the shell, and the coarser levels speak only beyond. Left to the
#: next level, whose spacing is 2.8 times as wide, a wall thinner than that spacing (a hollow
#: sphere, its wall 2.7 spacings thick, 10,000 samples) read inside at 449 of 200,000 random
#: points 2-4 spacings outside it and 323 in its cavity, where the finest patches' weights sum
#: below `TAU`; now 84 and 106.
VOLUME_FAR_FINEST = 5.0
#: The global base level takes at most this many volume constraints.
BASE_VOLUME = 3000


def coverage_at(origin: np.ndarray, radius: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The patches' total weight sum_i psi_i at the points `q` (host arrays, normalised units),
    from the patches' balls alone (before their fits, unlike `PartitionModel.coverage`): where
    it is below `TAU` the fallback takes over (see the module docstring)."""
    w = np.zeros(len(q))
    if len(q) == 0 or len(origin) == 0:
        return w
    hits = cKDTree(q).query_ball_point(origin, radius, workers=-1)
    counts = np.fromiter((len(x) for x in hits), dtype=np.int64, count=len(hits))
    if counts.sum() == 0:
        return w
    qi = np.concatenate([np.asarray(x, dtype=np.int64) for x in hits])
    pi = np.repeat(np.arange(len(origin)), counts)
    t2 = np.sum((q[qi] - origin[pi]) ** 2, axis=1) / radius[pi] ** 2
    psi = np.asarray(wendland_weight(jnp.asarray(t2)))
    return np.bincount(qi, psi, minlength=len(q))


def _level_volume(
    volume,
    xw: np.ndarray,
    h: np.ndarray,
    *,
    base: bool,
    seed: int,
    orphans=None,
    last=False,
    reach: float = VOLUME_FAR,
) -> np.ndarray:
    """The indices into `volume` (points, values) of the volume constraints of a level whose
    constraints are `xw`, `h` (see `fit_partition`), with the finer levels' `orphans` (indices)
    among them: at the base they come first, within `BASE_VOLUME`. The `last` level above the
    base takes every one beyond `VOLUME_NEAR` of its spacings, however far; the others those
    within `reach` of them."""
    none = np.zeros(0, dtype=np.int64)
    if volume is None or len(volume[1]) == 0:
        return none
    orphans = none if orphans is None else np.asarray(orphans, dtype=np.int64)
    spacing = point_spacing(xw[h == 0] if np.sum(h == 0) >= 2 else xw)
    # By |value|: the nearer of the probe's distances to the samples and to the winding number's
    # closing surface. The distance to this level's samples alone was tried (a probe over a hole
    # then joins the level whose patches reach it): measured on a virtual range scan of the cow,
    # Chamfer-L1 0.157% against 0.148% by |value|, and 0.293% against 0.290% on the bunny's.
    far = np.abs(volume[1])
    keep = far >= VOLUME_NEAR * spacing
    if not base:
        if not last:
            keep &= far <= reach * spacing
        return np.union1d(np.flatnonzero(keep), orphans)
    rng = np.random.default_rng(seed)
    if len(orphans) >= BASE_VOLUME:
        return np.sort(rng.choice(orphans, BASE_VOLUME, replace=False))
    keep[orphans] = False
    idx = np.flatnonzero(keep)
    if len(idx) > BASE_VOLUME - len(orphans):
        idx = rng.choice(idx, BASE_VOLUME - len(orphans), replace=False)
    return np.sort(np.concatenate([orphans, idx]))


def surface_of(xw: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The surface points and unit normals behind surface constraints (value 0 on the surface,
    +/- d at p +/- d n, each off-surface point nearest its own origin, as validated by
    `Constraints.from_points`, whose thin walls value it between d / 2 and d), or None when
    `xw`, `h` do not look like that (plain scattered data): fewer than a fifth of the values
    zero, or off-surface points whose nearest surface point is not at a distance between |h|
    and 2 |h|."""
    on = h == 0
    if on.sum() < 0.2 * len(h) or on.all():
        return None
    p, off, hv = xw[on], xw[~on], h[~on]
    dist, idx = cKDTree(p).query(off, workers=-1)
    tol = 1e-6 * np.abs(hv)
    partner = (dist >= np.abs(hv) - tol) & (dist <= 2.0 * np.abs(hv) + tol)
    if partner.mean() < 0.9:
        return None
    direction = np.sign(hv)[partner, None] * (off[partner] - p[idx[partner]])
    direction /= np.maximum(dist[partner], 1e-300)[:, None]
    normals = np.zeros_like(p)
    np.add.at(normals, idx[partner], direction)
    length = np.linalg.norm(normals, axis=1)
    has = length > 0.5  # a point with opposite partners that cancel has no usable normal
    return p[has], normals[has] / length[has, None]


def coarse_constraints(
    points: np.ndarray, normals: np.ndarray, between: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Constraints of a coarse level: `points` and validated off-surface points at
    `COARSE_OFFSET_SPACINGS` median spacings of `points`, shrunk where they would come nearer
    another part of the surface (the validation of `Constraints.from_points`; `between` as
    there: False where the fit approximates)."""
    from ._constraints import Constraints

    c = Constraints.from_points(
        points, normals, COARSE_OFFSET_SPACINGS * point_spacing(points), between=between
    )
    return np.asarray(c.points), np.asarray(c.values)


def check_memory(n: int, dim: int, leaf: int = LEAF) -> None:
    """Refuse a partition fit that cannot fit in memory, before it starts."""
    from ._fit import _available_memory

    m = MAX_POINTS
    patches = n / leaf * 8 / 7  # all levels
    need = patches * m * (dim + 2) * 8 * 2 + BATCH * (m + dim + 1) ** 2 * 8 * 4 + n * 8 * 40
    avail = _available_memory()
    if avail is not None and need > avail:
        raise InputError(
            f"the partition-of-unity fit of {n:,} constraints needs about {need / 2**30:.1f} GiB "
            f"but {avail / 2**30:.1f} GiB is available; use fewer points"
        )


# --- bulk evaluation (host-driven, patch by patch) ----------------------------------------------

#: Points per row of the bulk evaluator: one row is one patch and up to this many of its points.
ROW_POINTS = 32
#: Rows per compiled call of the bulk evaluator.
ROW_BATCH = 512
#: Points per host chunk of the bulk evaluator (bounds its pair lists).
BULK_CHUNK = 2**17
#: Concrete point sets at least this large are evaluated by the bulk evaluator.
BULK_MIN = 4096

_host_cache: dict[int, tuple] = {}


class _Host(NamedTuple):
    """Host (numpy) copies of a model's patch arrays, for the bulk evaluator."""

    origin: np.ndarray
    radius: np.ndarray
    centres: np.ndarray
    weights: np.ndarray
    coeffs: np.ndarray
    widths: np.ndarray  # each patch's number of real centres (they come first in its row)
    cell_row: np.ndarray
    table: np.ndarray
    grid_lo: np.ndarray
    cell_size: float
    balls: np.ndarray  # (P + 1, d + 1): origin and squared radius, one gather per candidate


def _host(model: PartitionModel) -> _Host:
    """The model's `_Host` arrays, cached per model (keyed on its weights array)."""
    key = id(model.weights)
    hit = _host_cache.get(key)
    if hit is not None and hit[0] is model.weights:
        return hit[1]
    weights = np.asarray(model.weights)
    nz = weights != 0
    widths = np.where(nz.any(axis=1), nz.shape[1] - np.argmax(nz[:, ::-1], axis=1), 0)
    host = _Host(
        np.asarray(model.origin),
        np.asarray(model.radius),
        np.asarray(model.centres),
        weights,
        np.asarray(model.coeffs),
        widths,
        np.asarray(model.cell_row),
        np.asarray(model.table),
        np.asarray(model.grid_lo),
        float(model.cell_size),
        np.concatenate([np.asarray(model.origin), np.asarray(model.radius)[:, None] ** 2], 1),
    )
    if len(_host_cache) > 16:
        _host_cache.clear()
    _host_cache[key] = (model.weights, host)
    return host


def _covering(host: _Host, dims: tuple[int, ...], xn: np.ndarray):
    """(point, patch) pairs with the point inside the patch's ball, sorted by patch."""
    cell = np.floor((xn - host.grid_lo) / host.cell_size).astype(np.int64)
    cell = np.clip(cell, 0, np.asarray(dims) - 1)
    pids = host.table[host.cell_row[np.ravel_multi_index(tuple(cell.T), dims)]]
    ball = host.balls[pids]  # (b, K, d + 1): centre and squared radius
    diff = xn[:, None, :] - ball[..., :-1]
    d2 = np.einsum("bkd,bkd->bk", diff, diff)
    pt, slot = np.nonzero(d2 < ball[..., -1])
    patch = pids[pt, slot]
    order = np.argsort(patch, kind="stable")
    return pt[order], patch[order]


@eqx.filter_jit
def _rows(kernel, degree: int, xr, c, wt, o, r, cf, grad: bool):
    """Blend terms psi_i f_i and psi_i (and their gradients) for rows of (patch, points): xr
    (R, S, d) normalised points; c (R, w, d), wt (R, w), o (R, d), r (R,), cf (R, k): each
    row's patch centres, weights, ball and polynomial coefficients."""
    n_rows, s, dim = xr.shape
    width = c.shape[1]
    r2 = jnp.zeros((n_rows, s, width), dtype=xr.dtype)
    for k in range(dim):
        r2 = r2 + (xr[:, :, None, k] - c[:, None, :, k]) ** 2
    u = (xr - o[:, None, :]) / r[:, None, None]
    t2 = jnp.sum(u * u, axis=-1)
    poly = poly_basis(u.reshape(-1, dim), degree).reshape(n_rows, s, -1)
    if not grad:
        local = jnp.einsum("rsw,rw->rs", kernel.from_r2(r2), wt)
        local = local + jnp.einsum("rsk,rk->rs", poly, cf)
        psi = wendland_weight(t2)
        return psi * local, psi
    # Gradients by hand, from d phi / d r^2 (one forward-mode pass over the elementwise kernel):
    # grad f_i = 2 sum_j w_j phi'(r_j^2) (x - c_j) + grad of the polynomial.
    phi, dphi = jax.jvp(kernel.from_r2, (r2,), (jnp.ones_like(r2),))
    local = jnp.einsum("rsw,rw->rs", phi, wt) + jnp.einsum("rsk,rk->rs", poly, cf)
    a = dphi * wt[:, None, :]
    glocal = 2.0 * (jnp.sum(a, axis=-1)[..., None] * xr - jnp.einsum("rsw,rwd->rsd", a, c))
    if degree >= 1:
        glocal = glocal + cf[:, None, 1:] / r[:, None, None]
    psi, dpsi = jax.jvp(wendland_weight, (t2,), (jnp.ones_like(t2),))
    gpsi = (2.0 * dpsi)[..., None] * u / r[:, None, None]
    return psi * local, psi, gpsi * local[..., None] + psi[..., None] * glocal, gpsi


def _pad_pow2(x: np.ndarray, least: int = 1024) -> np.ndarray:
    """`x` padded with copies of its first row to a power of two of rows (few compilations)."""
    n = len(x)
    size = max(least, 1 << max(n - 1, 0).bit_length())
    return np.concatenate([x, np.broadcast_to(x[:1], (size - n,) + x.shape[1:])])


def _blend_sums(model: PartitionModel, xn: np.ndarray, grad: bool):
    """sum_i psi_i f_i and sum_i psi_i (and gradients, normalised units) at points `xn` (b, d),
    evaluated patch by patch: the (point, patch) pairs are grouped by patch into rows of
    `ROW_POINTS` points, so each row reads its patch's centres once."""
    from ._sharding import pad_to_devices, split_over_devices

    b, dim = xn.shape
    host = _host(model)
    pt, patch = _covering(host, model.grid_dims, xn)
    num, den = np.zeros(b), np.zeros(b)
    gnum, gden = (np.zeros((b, dim)), np.zeros((b, dim))) if grad else (None, None)
    if len(pt) == 0:
        return num, den, gnum, gden
    first = np.flatnonzero(np.r_[True, patch[1:] != patch[:-1]])
    count = np.diff(np.r_[first, len(patch)])
    per = -(-count // ROW_POINTS)
    row_start = np.r_[0, np.cumsum(per)[:-1]]
    pos = np.arange(len(pt)) - np.repeat(first, count)
    row = np.repeat(row_start, count) + pos // ROW_POINTS
    n_rows = int(per.sum())
    members = np.full((n_rows, ROW_POINTS), b, dtype=np.int64)
    members[row, pos % ROW_POINTS] = pt
    row_patch = np.repeat(patch[first], per)
    # far away from every ball: the padding rows and points weigh nothing
    xpad = np.concatenate([xn, np.full((1, dim), 1e6)])
    batch = pad_to_devices(ROW_BATCH)
    dummy = model.n_patches
    m = host.centres.shape[1]
    for s0 in range(0, n_rows, batch):
        sel = np.arange(s0, s0 + batch)
        real = sel < n_rows
        sel = np.minimum(sel, n_rows - 1)
        rp = np.where(real, row_patch[sel], dummy)
        mem = np.where(real[:, None], members[sel], b)
        width = min(m, max(32, -(-int(host.widths[rp].max()) // 32) * 32))
        args = (
            xpad[mem],
            host.centres[rp, :width],
            host.weights[rp, :width],
            host.origin[rp],
            host.radius[rp],
            host.coeffs[rp],
        )
        out = split_over_devices(lambda *a: _rows(model.kernel, model.degree, *a, grad), *args)
        flat = mem.ravel()
        num += np.bincount(flat, out[0].ravel(), minlength=b + 1)[:b]
        den += np.bincount(flat, out[1].ravel(), minlength=b + 1)[:b]
        if grad:
            for k in range(dim):
                gnum[:, k] += np.bincount(flat, out[2][..., k].ravel(), minlength=b + 1)[:b]
                gden[:, k] += np.bincount(flat, out[3][..., k].ravel(), minlength=b + 1)[:b]
    return num, den, gnum, gden


def evaluate_many(model: PartitionModel, points, grad: bool = False):
    """f (and, with `grad`, grad f in the user's units) at many concrete points `points` (n, d),
    in the user's units, as numpy arrays (float64).

    The same function as `model(points)` and `model.gradient(points)`, computed the other way
    round: instead of every point gathering the centres of every candidate patch, every patch
    evaluates the points inside its ball (rows of `ROW_POINTS` points that read the patch's
    centres once), and the terms are summed per point on the host. Several times faster on large
    point sets (grids, bands); results agree with the gathered evaluation to rounding."""
    x = np.asarray(points, dtype=float)
    n, dim = x.shape
    scale, shift = float(model.scale), np.asarray(model.shift)
    vals = np.empty(n)
    grads = np.empty((n, dim)) if grad else None
    bg = model.background
    for s0 in range(0, n, BULK_CHUNK):
        xw = x[s0 : s0 + BULK_CHUNK]
        num, den, gnum, gden = _blend_sums(model, (xw - shift) / scale, grad)
        short = np.maximum(1.0 - den / TAU, 0.0)
        w0 = TAU * short * short
        need = np.flatnonzero(w0 > 0)
        g = np.zeros(len(xw))
        gg = np.zeros((len(xw), dim)) if grad else None
        if len(need):
            if isinstance(bg, PartitionModel):
                g[need], gsub = evaluate_many(bg, xw[need], grad)
            else:
                xq = jnp.asarray(_pad_pow2(xw[need]))
                g[need] = np.asarray(bg(xq))[: len(need)]
                gsub = np.asarray(bg.gradient(xq))[: len(need)] if grad else None
            if grad:
                gg[need] = gsub * scale  # normalised units, like gnum and gden
        top = num + w0 * g
        bottom = den + w0
        f = top / bottom
        vals[s0 : s0 + len(xw)] = f
        if grad:
            dw0 = (-2.0 * short)[:, None] * gden
            dtop = gnum + w0[:, None] * gg + g[:, None] * dw0
            dbottom = gden + dw0
            grads[s0 : s0 + len(xw)] = (dtop - f[:, None] * dbottom) / bottom[:, None] / scale
    return vals, grads
