"""Comparing a reconstructed surface with a reference mesh (host side: numpy and scipy).

Both meshes are sampled area-uniformly (`n` points each) and compared through nearest
neighbours between the two samples (KD-trees), as in the Occupancy Networks evaluation.
Distances are divided by the diagonal of the reference mesh's bounding box, so `0.004` means
0.4 % of the diagonal.

Both meshes are sampled from the same random stream (`seed`): identical meshes give exactly
0 distance, and meshes with the same connectivity get corresponding samples. For unrelated
tessellations the samples are independent, and the sampling itself adds about
`0.5 * sqrt(area / n) / diag` to the Chamfer distance (the mean nearest-neighbour distance of
uniform random points) and several times that to the Hausdorff distance; raise `n` to shrink it.
"""

from __future__ import annotations

import numpy as np

from ._errors import InputError
from .io import as_points

__all__ = [
    "sample_surface",
    "chamfer_l1",
    "hausdorff",
    "normal_consistency",
    "f_score",
    "evaluate",
]


def _mesh(mesh, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of a Mesh, a trimesh or a (vertices, faces) pair, validated."""
    if hasattr(mesh, "vertices") and hasattr(mesh, "faces"):
        v, f = mesh.vertices, mesh.faces
    elif isinstance(mesh, (tuple, list)) and len(mesh) == 2:
        v, f = mesh
    else:
        raise InputError(
            f"`{name}` must be a jaxrbf.io.Mesh or a (vertices, faces) pair, "
            f"got {type(mesh).__name__}"
        )
    v = as_points(v, f"{name} vertices", dims=(3,))
    f = np.asarray(f)
    if f.size == 0:
        raise InputError(f"`{name}` has no faces; the metrics compare triangle meshes (surfaces)")
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise InputError(
            f"`{name}` faces must be an integer array of shape (m, 3), got {f.dtype} {f.shape}"
        )
    if f.min() < 0 or f.max() >= len(v):
        raise InputError(
            f"`{name}` faces refer to vertices {f.min()}..{f.max()}, but there are {len(v)}"
        )
    return v, f.astype(np.int64, copy=False)


def _sample(v: np.ndarray, f: np.ndarray, n: int, seed: int, name: str):
    n = int(n)
    if n < 1:
        raise InputError(f"the number of samples `n` must be at least 1, got {n}")
    tri = v[f]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area2 = np.linalg.norm(cross, axis=1)
    total = area2.sum()
    if not (np.isfinite(total) and total > 0):
        raise InputError(f"`{name}` has zero surface area: all its triangles are degenerate")
    rng = np.random.default_rng(seed)
    cdf = np.cumsum(area2)
    idx = np.searchsorted(cdf, rng.random(n) * cdf[-1], side="right")
    idx = np.minimum(idx, len(f) - 1)
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    a, b, c = 1.0 - s, s * (1.0 - r2), s * r2
    t = tri[idx]
    points = a[:, None] * t[:, 0] + b[:, None] * t[:, 1] + c[:, None] * t[:, 2]
    normals = cross[idx] / area2[idx, None]
    return points, normals


def sample_surface(mesh, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Sample points uniformly by area on a triangle mesh.

    **Arguments:**
    - `mesh`: a `jaxrbf.io.Mesh` or a `(vertices, faces)` pair.
    - `n`: the number of points.
    - `seed`: seed of `np.random.default_rng`.

    **Returns:** `(points, normals)`, both (n, 3) float64; `normals` are the unit normals of the
    faces the points lie on (degenerate faces are never sampled).
    """
    v, f = _mesh(mesh, "mesh")
    return _sample(v, f, n, seed, "mesh")


def _diagonal(v: np.ndarray, f: np.ndarray) -> float:
    used = v[np.unique(f)]
    d = float(np.linalg.norm(used.max(axis=0) - used.min(axis=0)))
    if not d > 0:
        raise InputError("`ref` has a zero-size bounding box; distances cannot be normalised")
    return d


def _compare(pred, ref, n: int, seed: int):
    """Samples, nearest-neighbour distances and indices in both directions, and diag(ref)."""
    from scipy.spatial import cKDTree

    vp, fp = _mesh(pred, "pred")
    vr, fr = _mesh(ref, "ref")
    diag = _diagonal(vr, fr)
    pp, npred = _sample(vp, fp, n, seed, "pred")
    pr, nref = _sample(vr, fr, n, seed, "ref")
    d_pr, i_pr = cKDTree(pr).query(pp, k=1, workers=-1)  # pred -> ref (accuracy)
    d_rp, i_rp = cKDTree(pp).query(pr, k=1, workers=-1)  # ref -> pred (completeness)
    return dict(
        diag=diag,
        d_pr=d_pr / diag,
        d_rp=d_rp / diag,
        cos_pr=np.abs(np.sum(npred * nref[i_pr], axis=1)),
        cos_rp=np.abs(np.sum(nref * npred[i_rp], axis=1)),
    )


def _chamfer(c) -> float:
    return float(0.5 * (c["d_pr"].mean() + c["d_rp"].mean()))


def _hausdorff(c) -> float:
    return float(max(c["d_pr"].max(), c["d_rp"].max()))


def _normal_consistency(c) -> float:
    return float(np.clip(0.5 * (c["cos_pr"].mean() + c["cos_rp"].mean()), 0.0, 1.0))


def _check_threshold(threshold) -> float:
    try:
        t = float(threshold)
    except (TypeError, ValueError):
        t = float("nan")
    if not (np.isfinite(t) and t > 0):
        raise InputError(
            f"`threshold` must be a positive fraction of the reference diagonal, got {threshold!r}"
        )
    return t


def _f_score(c, t: float) -> float:
    precision = float(np.mean(c["d_pr"] < t))
    recall = float(np.mean(c["d_rp"] < t))
    if precision + recall == 0:
        return 0.0
    return 2.0 * precision * recall / (precision + recall)


def chamfer_l1(pred, ref, n: int = 100_000, seed: int = 0) -> float:
    """Symmetric Chamfer-L1 distance between two meshes.

    **Arguments:**
    - `pred`, `ref`: `jaxrbf.io.Mesh` objects or `(vertices, faces)` pairs.
    - `n`: samples per mesh. `seed`: sampling seed.

    **Returns:** `0.5 * (mean dist pred->ref + mean dist ref->pred) / diag(ref)`.
    """
    return _chamfer(_compare(pred, ref, n, seed))


def hausdorff(pred, ref, n: int = 100_000, seed: int = 0) -> float:
    """Symmetric Hausdorff distance between the two samples.

    **Arguments:**
    - `pred`, `ref`: `jaxrbf.io.Mesh` objects or `(vertices, faces)` pairs.
    - `n`: samples per mesh. `seed`: sampling seed.

    **Returns:** the larger of the two directed maxima, divided by diag(ref).
    """
    return _hausdorff(_compare(pred, ref, n, seed))


def normal_consistency(pred, ref, n: int = 100_000, seed: int = 0) -> float:
    """Agreement of face normals between nearest samples.

    **Arguments:**
    - `pred`, `ref`: `jaxrbf.io.Mesh` objects or `(vertices, faces)` pairs.
    - `n`: samples per mesh. `seed`: sampling seed.

    **Returns:** the mean of |cos| between each sample's normal and its nearest neighbour's on
    the other mesh, averaged over both directions; in [0, 1], 1 is best. Orientation is ignored.
    """
    return _normal_consistency(_compare(pred, ref, n, seed))


def f_score(pred, ref, threshold: float = 0.01, n: int = 100_000, seed: int = 0) -> float:
    """F-score at a distance threshold.

    **Arguments:**
    - `pred`, `ref`: `jaxrbf.io.Mesh` objects or `(vertices, faces)` pairs.
    - `threshold`: as a fraction of diag(ref).
    - `n`: samples per mesh. `seed`: sampling seed.

    **Returns:** `2PR / (P + R)` (0 when both are 0), where the precision P is the fraction of
    pred samples closer than the threshold to ref's samples, and the recall R the reverse.
    """
    t = _check_threshold(threshold)
    return _f_score(_compare(pred, ref, n, seed), t)


def evaluate(
    pred, ref, n: int = 100_000, seed: int = 0, threshold: float = 0.01
) -> dict[str, float]:
    """All metrics from one sampling and one pair of nearest-neighbour queries.

    **Arguments:**
    - `pred`, `ref`: `jaxrbf.io.Mesh` objects or `(vertices, faces)` pairs.
    - `n`: samples per mesh. `seed`: sampling seed.
    - `threshold`: F-score threshold as a fraction of diag(ref).

    **Returns:** a dict with `chamfer_l1`, `hausdorff`, `normal_consistency`, `f_score` and the
    `threshold` used (distances as fractions of diag(ref)).
    """
    t = _check_threshold(threshold)
    c = _compare(pred, ref, n, seed)
    return {
        "chamfer_l1": _chamfer(c),
        "hausdorff": _hausdorff(c),
        "normal_consistency": _normal_consistency(c),
        "f_score": _f_score(c, t),
        "threshold": t,
    }
