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

import sys
import time
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, Float, Int

from ._constraints import log
from ._errors import InputError, SolveError
from ._model import AbstractModel, kernel_block, poly_basis
from ._schwarz import _kd_leaves
from .kernels import AbstractKernel, _safe_sqrt

#: Constraints per k-d leaf. A patch's ball then holds about 4-5x as many (it reaches into the
#: neighbouring leaves), which is what the local solve costs: O(m^3) per patch.
LEAF = 24
#: Patch radius as a multiple of its leaf box's half-diagonal: the overlap between patches.
ALPHA = 1.25
MIN_POINTS = 48
MAX_POINTS = 128
#: Below this total weight of the patches, the coarser fallback model takes over (see above).
TAU = 0.005
#: Each coarser level keeps one constraint in this many.
COARSENING = 8
#: A level of at most this many constraints is a single global fit.
BASE_SIZE = 3000
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
    size = max(len(lf) for lf in leaves)
    grid = np.array([np.pad(lf, (0, size - len(lf)), mode="edge") for lf in leaves])
    pts = x[grid]  # (P, size, d), padded with repeats
    origin = 0.5 * (pts.min(axis=1) + pts.max(axis=1))
    reach = np.sqrt(np.max(np.sum((pts - origin[:, None]) ** 2, axis=2), axis=1))
    return origin, alpha * np.maximum(reach, 1e-12)


def make_patches(
    x: np.ndarray,
    leaf: int = LEAF,
    alpha: float = ALPHA,
    min_points: int = MIN_POINTS,
    max_points: int = MAX_POINTS,
) -> Patches:
    """The patches of normalised constraint points `x` (n, d); see the module docstring.

    Patch i is centred on leaf i's box; its radius is `alpha` x the distance from there to the
    leaf's farthest point (so every leaf point sits at t <= 1 / alpha, where its own weight is at
    least phi_W(1 / alpha)), grown to reach at least `min_points` constraints. Its fit takes every
    constraint in the ball; a leaf whose ball would hold more than `max_points` (where sheets of
    the surface come close, or the leaf is elongated) is split in two until none does, so every
    local fit interpolates every constraint its weight reaches."""
    from scipy.spatial import cKDTree

    n, _ = x.shape
    tree = cKDTree(x)
    leaves = _kd_leaves(x, np.arange(n), max(1, -(-n // leaf)))
    for _ in range(30):
        origin, radius = _balls(x, leaves, alpha)
        count = tree.query_ball_point(origin, radius, return_length=True, workers=-1)
        split = (count > max_points) & np.array([len(lf) > 2 for lf in leaves])
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


def lookup_grid(origin: np.ndarray, radius: np.ndarray, cell_factor: float = 0.25):
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


@eqx.filter_jit
def _fit_batch(kernel, xs, hs, mask, origin, radius, degree: int, smoothing):
    """Local saddle-system solves for a batch of padded patches (vmap). Returns weights, coeffs
    and each patch's relative residual on its own constraints."""

    def one(x, h, keep, o, r):
        m = x.shape[0]
        both = keep[:, None] & keep[None, :]
        a = kernel_block(kernel, x, x) + smoothing * jnp.eye(m, dtype=x.dtype)
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
            ev = jnp.linalg.eigvalsh(cov)
            flat = ev[0] <= 1e-10 * jnp.maximum(ev[-1], 1e-300)
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

    return jax.vmap(one)(xs, hs, mask, origin, radius)


def _progress(total: int, desc: str, verbose: bool):
    from tqdm import tqdm

    return tqdm(
        total=total,
        desc=desc,
        unit="patch",
        disable=not (verbose or sys.stderr.isatty()),
        file=sys.stderr,
        leave=False,
    )


def fit_patches(
    kernel, xn, h, degree, smoothing, patches: Patches, *, verbose=False, desc="patches"
):
    """Solve every patch's local system, in fixed-size batches. Returns (weights, coeffs,
    worst local residual), the arrays with the dummy row appended."""
    from ._sharding import pad_to_devices, split_over_devices

    n_p, m = patches.members.shape
    dim = xn.shape[1]
    xpad = np.concatenate([xn, np.zeros((1, dim))])
    hpad = np.concatenate([h, np.zeros(1)])
    k = poly_basis(jnp.zeros((1, dim)), degree).shape[1]
    weights = np.zeros((n_p + 1, m))
    coeffs = np.zeros((n_p + 1, k))
    worst = 0.0
    batch = pad_to_devices(min(BATCH, n_p))
    with _progress(n_p, desc, verbose) as bar:
        for start in range(0, n_p, batch):
            sel = np.arange(start, start + batch)
            real = sel < n_p
            sel = np.where(real, sel, 0)
            # Pad this batch only to its own largest patch (rounded up: few distinct shapes,
            # so few compilations); patches come sorted by size.
            width = min(m, -(-int(patches.mask[sel].sum(axis=1).max()) // 32) * 32)
            mem = patches.members[sel, :width]
            mask = patches.mask[sel, :width] & real[:, None]
            args = (xpad[mem], hpad[mem], mask, patches.origin[sel], patches.radius[sel])
            w, c, rel = split_over_devices(
                lambda *a: _fit_batch(kernel, *a, degree, smoothing), *args
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
):
    """The partition-of-unity model of constraints `xw` with values `h`, both in the user's units
    (as are `kernel`'s radius and `smoothing`); `shift` and `scale` map them into the unit box.

    Recursive: the fallback is the same construction on a 1/`COARSENING` subsample, down to
    `BASE_SIZE` constraints, which get one global fit (`jaxrbf.fit`)."""
    from ._fit import fit

    leaf = LEAF if leaf is None else leaf
    base_size = BASE_SIZE if base_size is None else base_size
    n = len(xw)
    t0 = time.perf_counter()
    if n <= base_size:
        # The coarsest fallback only has to give the right sign away from the data, so it is
        # always the robust polyharmonic fit (r^3 in 3-D, r^2 log r in 2-D, CG), whatever the
        # patches use: a Gaussian base would be as ill-conditioned as a dense Gaussian fit.
        base_kernel = "cubic" if xw.shape[1] == 3 else "thin-plate"
        base = fit(
            xw, h, kernel=base_kernel, degree=1, smoothing=smoothing, solver="cg", method="dense"
        )
        if verbose:
            log(
                f"level {level}: global {base_kernel} fit of {n:,} constraints in "
                f"{time.perf_counter() - t0:.1f} s (fallback far from the data)"
            )
        return base
    rng = np.random.default_rng(seed + level)
    sub = np.sort(rng.choice(n, max(base_size // 2, n // COARSENING), replace=False))
    background = fit_partition(
        xw[sub],
        h[sub],
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
    )
    t0 = time.perf_counter()
    xn = (xw - shift) / scale
    patches = make_patches(xn, leaf=leaf)
    kn = kernel.scaled(1.0 / scale)
    weights, coeffs, worst = fit_patches(
        kn,
        xn,
        h,
        degree,
        smoothing / scale**kernel.homogeneity,
        patches,
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


def constraint_residual(
    model: AbstractModel, xw: np.ndarray, h: np.ndarray, sample: int = 50_000, seed: int = 0
) -> float:
    """max |f(x_i) - h_i| / max |h| over the constraints (a random sample of `sample` of them)."""
    n = len(xw)
    if n > sample:
        idx = np.random.default_rng(seed).choice(n, sample, replace=False)
        xw, h = xw[idx], h[idx]
    err = np.abs(np.asarray(model(jnp.asarray(xw))) - h)
    return float(err.max() / max(np.abs(h).max(), 1e-300))


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
