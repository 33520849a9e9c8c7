"""`choose_smoothing`: the smoothing lambda for a noisy point cloud, chosen by the held-out error.

An interpolating fit reproduces the scanner's noise as bumps; with smoothing lambda > 0 the system
is A + lambda I and the fit approximates. How much is right depends on the noise, the point
density and the kernel, so it is chosen by the tuning objective (`jaxrbf.held_out_error`): a fit
that follows the noise passes further from held-out samples (and its normals turn further from
theirs) than one that follows the surface underneath.

The choice is made on a few crops of the cloud at its own density (the k nearest neighbours of a
random sample): a crop holds as many points per patch as the real fit, so the lambda it picks means
the same there, whether the full fit is dense or a partition of unity, for any number of points.
Each crop's held-out points are taken from its interior only (its rim has no data beyond it).

Lambda is searched on a grid in log space, in units of diagonal^h (h, the kernel's homogeneity,
so that a choice does not depend on the input's units), refined by a parabola through the best
grid point and its neighbours. Interpolation (lambda = 0) is one of the candidates: clean input
keeps it. Host loop over dense float64 fits of `CROP_POINTS` points each.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ._constraints import log
from ._errors import InputError

#: Points per crop: 1,000 points (about 3,000 constraints) fit densely in ~0.3 s.
CROP_POINTS = 1000
#: Crops per choice; their objectives are averaged.
CROPS = 3
#: Candidate lambdas, in units of diagonal^h (0 first: interpolation).
GRID = (0.0, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1)
#: Held-out points are the crop's points within this fraction of its radius from its centre.
INTERIOR = 0.6
#: A candidate with a larger lambda replaces the best only when its objective is lower by more
#: than this fraction (a flat landscape keeps the lesser smoothing, and so the detail).
TOLERANCE = 0.02


@dataclass
class SmoothingReport:
    """What `choose_smoothing` did. `smoothing` is in the points' units (give it to `fit`);
    `relative` is it in units of diagonal^h; `grid` and `objective` the candidates (relative) and
    their mean held-out error over the crops."""

    smoothing: float
    relative: float
    grid: tuple[float, ...]
    objective: tuple[float, ...]
    crops: int
    crop_points: int
    seconds: float

    def summary(self) -> str:
        best = int(np.argmin(self.objective))
        rows = ", ".join(
            f"{g:.0e}: {o:.4f}" if np.isfinite(o) else f"{g:.0e}: failed"
            for g, o in zip(self.grid, self.objective, strict=True)
        )
        kind = (
            "interpolation (no smoothing: the held-out error does not improve with it)"
            if self.smoothing == 0
            else f"lambda = {self.relative:.2e} x diagonal^h ({self.smoothing:.3e} in the points' units)"
        )
        return (
            f"denoise: {kind}; held-out error on {self.crops} crops of {self.crop_points:,} "
            f"points ({self.seconds:.1f} s), best grid point {self.grid[best]:.0e}; by lambda: {rows}"
        )


def _crops(points, count, size, seed):
    """Index arrays of `count` crops: the `size` nearest neighbours of spread-out seed points."""
    from scipy.spatial import cKDTree

    tree = cKDTree(points)
    rng = np.random.default_rng(seed)
    # Farthest-point seeds from a random start spread the crops over the shape.
    seeds = [int(rng.integers(len(points)))]
    dist = np.linalg.norm(points - points[seeds[0]], axis=1)
    for _ in range(count - 1):
        seeds.append(int(np.argmax(dist)))
        dist = np.minimum(dist, np.linalg.norm(points - points[seeds[-1]], axis=1))
    out = []
    for s in seeds:
        d, idx = tree.query(points[s], k=size, workers=-1)
        inner = np.flatnonzero(d <= INTERIOR * d[-1])
        out.append((idx, inner))
    return out


def choose_smoothing(
    points,
    normals,
    *,
    kernel="cubic",
    offset: float,
    radius: float | None = None,
    degree: int = 1,
    crops: int = CROPS,
    crop_points: int = CROP_POINTS,
    grid=GRID,
    seed: int = 0,
    verbose: bool = False,
) -> SmoothingReport:
    """The smoothing lambda of a surface fit of `points` with outward `normals`, chosen by the
    held-out error (`jaxrbf.held_out_error`) on `crops` crops of `crop_points` points each.

    **Arguments:** `kernel`, `offset` (d), `radius` (kernels with one) and `degree` as the fit
    will use them, in the points' units; `grid`: candidate lambdas in units of diagonal^h.

    **Returns:** a `SmoothingReport`; its `smoothing` goes to `fit(..., smoothing=...)`.
    """
    from ._prepare import diagonal
    from .kernels import make_kernel
    from .objectives import held_out_error

    t0 = time.perf_counter()
    p = np.asarray(points, dtype=float)
    nrm = np.asarray(normals, dtype=float)
    if p.ndim != 2 or nrm.shape != p.shape:
        raise InputError(
            f"`points` and `normals` must be (n, d) arrays of one shape, got {p.shape} and {nrm.shape}"
        )
    grid = tuple(float(g) for g in grid)
    if not grid or any(not (np.isfinite(g) and g >= 0) for g in grid):
        raise InputError(f"`grid` must hold lambdas >= 0, got {grid}")
    size = min(int(crop_points), len(p))
    if size < 50:
        raise InputError(f"choosing the smoothing needs at least 50 points, got {len(p)}")
    kern = make_kernel(kernel, radius)
    unit = diagonal(p) ** kern.homogeneity
    parts = _crops(p, max(1, int(crops)), size, seed)
    scores = np.zeros(len(grid))
    for idx, inner in parts:
        pc, nc = p[idx], nrm[idx]
        test = np.random.default_rng(seed).choice(inner, max(1, len(inner) // 3), replace=False)
        for i, g in enumerate(grid):
            e = float(
                held_out_error(
                    pc,
                    nc,
                    kernel=kern.name,
                    offset=offset,
                    radius=radius,
                    smoothing=g * unit,
                    degree=degree,
                    test=np.sort(test),
                )
            )
            scores[i] += e / len(parts)
    best = int(np.argmin(scores))
    for i in range(best):  # the least smoothing within TOLERANCE of the best
        if scores[i] <= scores[best] * (1 + TOLERANCE):
            best = i
            break
    rel = grid[best]
    if (
        0 < best < len(grid) - 1
        and grid[best - 1] > 0
        and all(np.isfinite(scores[best - 1 : best + 2]))
    ):
        # Parabola in log lambda through the best point and its neighbours.
        x = np.log(np.asarray(grid[best - 1 : best + 2]))
        y = scores[best - 1 : best + 2]
        a, b, _ = np.polyfit(x, y, 2)
        if a > 0:
            rel = float(np.exp(np.clip(-b / (2 * a), x[0], x[2])))
    report = SmoothingReport(
        smoothing=rel * unit,
        relative=rel,
        grid=grid,
        objective=tuple(float(s) for s in scores),
        crops=len(parts),
        crop_points=size,
        seconds=time.perf_counter() - t0,
    )
    if verbose:
        log(report.summary())
    return report
