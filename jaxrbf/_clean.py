"""Cleaning raw scans and checking meshes: statistical outlier removal, boundary loops, watertightness.

Host work (numpy/scipy).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._errors import InputError


@dataclasses.dataclass(frozen=True)
class OutlierReport:
    """What `remove_outliers` did: `dropped` of `n` points, with mean neighbour distance above
    `threshold` (`k` neighbours, `std_ratio` standard deviations above the mean)."""

    n: int
    dropped: int
    k: int
    std_ratio: float
    threshold: float

    def summary(self) -> str:
        return (
            f"removed {self.dropped:,} outliers of {self.n:,} points (mean distance to {self.k} "
            f"neighbours above {self.threshold:.4g}, {self.std_ratio:g} std above the mean)"
        )


def remove_outliers(points, normals=None, k: int = 16, std_ratio: float = 2.0):
    """Statistical outlier removal (as in PCL's `StatisticalOutlierRemoval` and Open3D's
    `remove_statistical_outlier`): a point whose mean distance to its `k` nearest neighbours is
    more than `std_ratio` standard deviations above the mean of that distance over all points is
    dropped.

    **Arguments:**
    - `points`: (n, d) points; `normals`: (n, d) or `None` (filtered alongside).
    - `k`: neighbours; `std_ratio`: the threshold in standard deviations.

    **Returns:** `(points, normals, report)` with the kept rows (`normals` stays `None` if it was)
    and an `OutlierReport`.
    """
    from scipy.spatial import cKDTree

    from .io import as_points

    p = as_points(points, "points")
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != p.shape:
            raise InputError(
                f"`normals` must have the shape of `points` {p.shape}, got {normals.shape}"
            )
    k = int(k)
    if k < 1:
        raise InputError(f"`k` must be at least 1 neighbour, got {k}")
    if not (np.isfinite(std_ratio) and std_ratio > 0):
        raise InputError(f"`std_ratio` must be a positive number, got {std_ratio!r}")
    if len(p) < k + 1:
        raise InputError(
            f"`points` has {len(p):,} points; outlier removal with k = {k} neighbours needs at "
            f"least {k + 1} (lower `k`)"
        )
    dist, _ = cKDTree(p).query(p, k=k + 1, workers=-1)
    mean = dist[:, 1:].mean(axis=1)
    threshold = float(mean.mean() + std_ratio * mean.std())
    keep = mean <= threshold
    report = OutlierReport(
        n=len(p), dropped=int((~keep).sum()), k=k, std_ratio=float(std_ratio), threshold=threshold
    )
    return p[keep], (None if normals is None else normals[keep]), report


def _faces(mesh) -> np.ndarray:
    f = np.asarray(getattr(mesh, "faces", mesh))
    if f.ndim != 2 or f.shape[1] != 3:
        raise InputError(f"expected a triangle mesh with (m, 3) faces, got shape {f.shape}")
    return f.astype(np.int64)


def _directed_edges(f: np.ndarray) -> np.ndarray:
    return np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])


def boundary_loops(mesh) -> int:
    """Number of closed boundary loops of a triangle mesh (a `Mesh`, or an (m, 3) face array):
    the edges used by one face only, chained into loops (connected components of the boundary
    edge graph). 0 for a closed mesh, 1 for a sphere with one hole."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    f = _faces(mesh)
    if len(f) == 0:
        return 0
    und = np.sort(_directed_edges(f), axis=1)
    edges, count = np.unique(und, axis=0, return_counts=True)
    b = edges[count == 1]
    if len(b) == 0:
        return 0
    verts, local = np.unique(b, return_inverse=True)
    local = local.reshape(b.shape)
    m = len(verts)
    g = coo_matrix((np.ones(len(b)), (local[:, 0], local[:, 1])), shape=(m, m))
    n_comp, _ = connected_components(g, directed=False)
    return int(n_comp)


def is_watertight(mesh) -> bool:
    """True when every edge of the triangle mesh is used by exactly two faces, in opposite
    directions (consistently oriented faces), so that the mesh encloses a volume."""
    f = _faces(mesh)
    if len(f) == 0:
        return False
    d = _directed_edges(f)
    und = np.sort(d, axis=1)
    _, count = np.unique(und, axis=0, return_counts=True)
    if not np.all(count == 2):
        return False
    # Each directed edge once: with two uses per edge, the two are then opposite.
    return len(np.unique(d, axis=0)) == len(d)
