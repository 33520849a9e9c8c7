"""Normals for bare point clouds: PCA over nearest neighbours, then a consistent, outward orientation.

Host work (numpy/scipy), like the rest of the input end of the pipeline (see DESIGN.md).

Method (Hoppe, DeRose, Duchamp, McDonald & Stuetzle 1992, "Surface reconstruction from unorganized
points", SIGGRAPH): the unoriented normal of a point is the eigenvector of the smallest eigenvalue of
the covariance of its k nearest neighbours. Orientation is then propagated along a minimum spanning
tree of the "Riemannian graph" (the symmetrised kNN graph with edge cost 1 - |n_i . n_j|): the tree
prefers edges between nearly parallel tangent planes, where flipping a child to agree with its
parent is safe. One tree per connected component; each component is finally turned outward by a
vote of n . (p - centroid) over its convex-hull points.

Thin parts (two sheets of surface closer than the neighbourhood, such as the two faces of a thin
plate) are the classic failure: an edge that jumps across the gap joins points with anti-parallel
normals, |n_i . n_j| = 1, so the plain cost is zero and the tree may propagate through it and flip a
whole sheet the wrong way. Here every edge also pays for how much it runs along the normals,
(|e . n_i| + |e . n_j|) / 2 with e the unit edge direction, and for its length relative to the local
spacing: an edge across a gap runs along the normals and costs ~1, an edge within a sheet runs in the
tangent plane and costs ~0, so the tree stays on each sheet and crosses only where it must.
"""

from __future__ import annotations

import dataclasses
import sys

import numpy as np

from ._errors import InputError

#: MST edges whose normals make more than this angle (degrees) are reported as unsure.
UNSURE_ANGLE = 60.0
K_MIN, K_MAX = 8, 30
#: A tree edge crosses a gap between two sheets when it runs this close to both normals (cosine).
CROSS = 0.5
#: Rounds of the neighbour vote after the tree (see `_vote`), and the majority it needs to flip.
VOTE_ROUNDS, VOTE_MAJORITY = 3, 0.6
#: A normal whose mean |cos| with its neighbours' is below this is refilled from theirs.
DOUBT = 0.5
#: Trimmed neighbourhoods must be this much flatter to replace the plain PCA (see `_one_sheet`).
SHEET_GAIN = 4.0


@dataclasses.dataclass(frozen=True)
class NormalsReport:
    """What `estimate_normals` did.

    - `k`: neighbours used for each PCA.
    - `flipped`: fraction of the PCA normals that orientation flipped.
    - `unsure`: points whose tree edge to their parent joins normals more than `UNSURE_ANGLE`
      degrees apart (their orientation is a guess: sharp edges, thin parts, noise).
    - `components`: connected components of the neighbour graph (one tree and one outward
      check each).
    - `n`: number of points.
    """

    k: int
    flipped: float
    unsure: int
    components: int
    n: int

    def summary(self) -> str:
        return (
            f"estimated normals of {self.n:,} points: k = {self.k}, {self.components} "
            f"component(s), {100 * self.flipped:.1f}% flipped by orientation, {self.unsure:,} unsure"
        )


def default_k(n: int) -> int:
    """Neighbours for the PCA: grows slowly with the number of points (2 log2 n, within 8..30),
    since denser scans resolve more detail but also carry more noise per neighbourhood."""
    return int(np.clip(round(2 * np.log2(max(n, 2))), K_MIN, K_MAX))


def _check_points(points) -> np.ndarray:
    try:
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InputError(f"`points` must be an (n, 3) array of numbers: {e}") from None
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"`points` must be an (n, 3) array, got shape {p.shape}")
    bad = int((~np.isfinite(p)).any(axis=1).sum())
    if bad:
        raise InputError(
            f"`points` has {bad:,} rows with NaN or infinite coordinates; drop them first"
        )
    return p


def _pca(p: np.ndarray, idx: np.ndarray, w: np.ndarray | None = None):
    """Unit eigenvectors of the smallest covariance eigenvalue of each neighbourhood `p[idx]`
    (rows weighted by `w`, (n, k) of 0/1), and that eigenvalue over the sum of all three."""
    nb = p[idx]  # (n, k, 3)
    if w is None:
        w = np.ones(idx.shape)
    mean = np.einsum("nk,nki->ni", w, nb) / w.sum(axis=1)[:, None]
    nb = nb - mean[:, None, :]
    cov = np.einsum("nk,nki,nkj->nij", w, nb, nb)
    val, vec = np.linalg.eigh(cov)
    return vec[:, :, 0], val[:, 0] / np.maximum(val.sum(axis=1), 1e-300)


def _one_sheet(p: np.ndarray, idx: np.ndarray):
    """PCA normals robust to a second sheet of surface inside the neighbourhood (thin parts).

    Plain PCA over a neighbourhood that spans both faces of a thin plate fits a tilted plane
    through both. Here each neighbourhood is trimmed to the neighbours whose offset along the
    current normal is under half the largest offset, and the trimmed fit is kept where it is far
    flatter (residual eigenvalue down by `SHEET_GAIN`): a two-sheet neighbourhood splits into its
    sheets, a curved or noisy single sheet barely gains and keeps every neighbour. Two rounds.
    """
    normals, flat = _pca(p, idx)
    for _ in range(2):
        off = np.abs(np.einsum("nki,ni->nk", p[idx] - p[:, None, :], normals))
        keep = (off <= 0.5 * off.max(axis=1, keepdims=True)).astype(float)
        ok = keep.sum(axis=1) >= 4
        n2, flat2 = _pca(p, idx, np.where(ok[:, None], keep, 1.0))
        use = ok & (flat2 * SHEET_GAIN < flat)
        normals = np.where(use[:, None], n2, normals)
        flat = np.where(use, flat2, flat)
    return normals


def _outward(p: np.ndarray, n: np.ndarray) -> bool:
    """True when the normals of one component point away from its centroid, by a vote over its
    convex-hull points (or over all points when the hull is degenerate)."""
    c = p.mean(axis=0)
    pick = np.arange(len(p))
    if len(p) >= 4:
        try:
            from scipy.spatial import ConvexHull

            pick = ConvexHull(p).vertices
        except Exception:  # flat or degenerate component: vote over every point
            pass
    d = p[pick] - c
    w = np.einsum("ij,ij->i", n[pick], d)
    return bool(w.sum() >= 0)


def _both_ways(rows, cols, keep) -> tuple[np.ndarray, np.ndarray]:
    """The edges `rows[keep] -> cols[keep]` in both directions (for per-point sums)."""
    r, c = rows[keep], cols[keep]
    return np.concatenate([r, c]), np.concatenate([c, r])


def _vote(normals, r, c) -> tuple[np.ndarray, int]:
    """Flip the normals that most of their neighbours on the same sheet disagree with.

    One wrong turn in the spanning tree flips a whole branch; on noisy scans most branches that go
    wrong are a single leaf (a point whose noisy neighbourhood tilted its normal, or whose edge to
    its parent looked like a gap between two sheets). Each round, a point whose neighbours (the
    directed edges `r -> c`, both ways, weighted by |n_i . n_j|; the caller leaves out those
    whose offset runs along the normals: they may lie on the other face of a thin part) disagree
    with it by a weighted majority of `VOTE_MAJORITY` is flipped. Returns the normals and how
    many it flipped in all."""
    n_pts = len(normals)
    total = 0
    for _ in range(VOTE_ROUNDS):
        dot = np.einsum("ij,ij->i", normals[r], normals[c])
        w = np.abs(dot)
        against = np.bincount(r, weights=w * (dot < 0), minlength=n_pts)
        weight = np.bincount(r, weights=w, minlength=n_pts)
        flip = against > VOTE_MAJORITY * np.maximum(weight, 1e-300)
        if not flip.any():
            break
        normals = np.where(flip[:, None], -normals, normals)
        total += int(flip.sum())
    return normals, total


def _fill_doubtful(normals, r, c) -> np.ndarray:
    """Replace the normals whose axis disagrees with most of their neighbours' (mean |n_i . n_j|
    below `DOUBT`) by the mean of those neighbours' normals, weighted by their own agreement.

    At a sharp edge or a corner the neighbourhood is no plane, and the PCA axis can come out
    across the surface instead of through it; its sign is then a coin toss. The neighbours'
    oriented normals average to the bisector of the faces that meet there, which points out.
    Edges `r -> c` as for `_vote`."""
    n_pts = len(normals)
    agree = np.abs(np.einsum("ij,ij->i", normals[r], normals[c]))
    count = np.bincount(r, minlength=n_pts)
    trust = np.bincount(r, weights=agree, minlength=n_pts) / np.maximum(count, 1)
    doubt = (trust < DOUBT) & (count > 0)
    if not doubt.any():
        return normals
    pick = doubt[r]
    acc = np.zeros_like(normals)
    np.add.at(acc, r[pick], trust[c[pick], None] * normals[c[pick]])
    size = np.linalg.norm(acc, axis=1)
    ok = doubt & (size > 1e-12)
    out = normals.copy()
    out[ok] = acc[ok] / size[ok, None]
    return out


def _oriented(p, normals, dist, idx, k: int, refill: bool):
    """The unoriented `normals` of the distinct points `p` (their `k` + 1 nearest: `dist`,
    `idx`) oriented along a minimum spanning tree, each component turned outward, then the
    neighbour vote (`_vote`) and, with `refill`, the doubtful ones refilled from their neighbours
    (`_fill_doubtful`): `(normals, unsure, components)`."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import (
        breadth_first_order,
        connected_components,
        minimum_spanning_tree,
    )

    n_pts = len(p)

    # Riemannian graph over the nearest neighbours (fewer than the PCA's: short edges only).
    kg = min(k, 10)
    h = np.maximum(dist[:, kg], 1e-300)  # local spacing scale of each point
    rows = np.repeat(np.arange(n_pts), kg)
    cols = idx[:, 1 : kg + 1].reshape(-1)
    e = p[cols] - p[rows]
    length = np.linalg.norm(e, axis=1)
    e = e / np.maximum(length, 1e-300)[:, None]
    ni, nj = normals[rows], normals[cols]
    parallel = 1.0 - np.abs(np.einsum("ij,ij->i", ni, nj))
    across = 0.5 * (np.abs(np.einsum("ij,ij->i", e, ni)) + np.abs(np.einsum("ij,ij->i", e, nj)))
    # Symmetric in i and j, so that the union of both directions is well defined; > 0 because
    # csgraph reads a zero as no edge.
    w = parallel + across + 0.2 * length / (h[rows] + h[cols]) + 1e-9
    g = coo_matrix((w, (rows, cols)), shape=(n_pts, n_pts)).tocsr()
    g = g.maximum(g.T).tocsr()
    mst = minimum_spanning_tree(g)
    mst = (mst + mst.T).tocsr()
    n_comp, labels = connected_components(mst, directed=False)

    sign = np.ones(n_pts)
    unsure = 0
    centre_all = p.mean(axis=0)
    for c in range(n_comp):
        members = np.flatnonzero(labels == c)
        # Root: the member farthest from the component's centre, a hull point, turned outward.
        cc = p[members].mean(axis=0) if len(members) > 1 else centre_all
        root = members[np.argmax(np.linalg.norm(p[members] - cc, axis=1))]
        order, pred = breadth_first_order(mst, root, directed=False, return_predecessors=True)
        for i in order[1:]:
            par = pred[i]
            e = p[i] - p[par]
            e = e / max(float(np.linalg.norm(e)), 1e-300)
            a, b = float(normals[par] @ e), float(normals[i] @ e)
            if min(abs(a), abs(b)) > CROSS:
                # The edge crosses a gap between two sheets (it runs along both normals): take the
                # gap for a thin solid, whose normals point away from each other.
                sign[i] = sign[par] * (-1.0 if a * b > 0 else 1.0)
                continue
            dot = float(normals[i] @ normals[par]) * sign[par]
            if dot < 0:
                sign[i] = -1.0
            if abs(dot) < np.cos(np.radians(UNSURE_ANGLE)):
                unsure += 1
        oriented = normals[members] * sign[members, None]
        if not _outward(p[members], oriented):
            sign[members] *= -1.0

    normals = normals * sign[:, None]
    # The vote looks wider than the tree (all k neighbours of the PCA): on noisy scans the
    # nearest neighbours are often offset along the normal rather than beside the point.
    vr = np.repeat(np.arange(n_pts), k)
    vc = idx[:, 1:].reshape(-1)
    ve = p[vc] - p[vr]
    ve /= np.maximum(np.linalg.norm(ve, axis=1), 1e-300)[:, None]
    along = np.minimum(
        np.abs(np.einsum("ij,ij->i", ve, normals[vr])),
        np.abs(np.einsum("ij,ij->i", ve, normals[vc])),
    )
    r, c = _both_ways(vr, vc, along <= CROSS)
    normals, _ = _vote(normals, r, c)
    return (_fill_doubtful(normals, r, c) if refill else normals), unsure, n_comp


def estimate_normals(points, k: int | None = None, verbose: bool = False):
    """Oriented unit normals of a bare 3-D point cloud.

    **Arguments:**
    - `points`: (n, 3) points sampled on one or more closed surfaces.
    - `k`: neighbours for each PCA (default: `default_k(n)`, 2 log2 n within 8..30).
    - `verbose`: print the report to stderr.

    **Returns:** `(normals, report)`: (n, 3) unit normals, pointing out of each connected
    component, and a `NormalsReport`.

    Exact duplicate points share one normal. Points on one plane get the plane's normal (its
    side is arbitrary but consistent). Nested surfaces (a hollow shell's inner wall) are turned
    outward too, which is wrong for them: give normals for such input.
    """
    from scipy.spatial import cKDTree

    p_all = _check_points(points)
    # Exact duplicates: work on the distinct points, copy back at the end.
    p, inverse = np.unique(p_all, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    n_pts = len(p)
    if k is None:
        k = default_k(n_pts)
    k = int(k)
    if k < 3:
        raise InputError(f"`k` must be at least 3 neighbours for a tangent plane, got {k}")
    if n_pts < k + 1:
        dup = (
            f" ({len(p_all) - n_pts:,} of the {len(p_all):,} are duplicates)"
            if n_pts < len(p_all)
            else ""
        )
        raise InputError(
            f"there are only {n_pts:,} distinct points{dup}; normal estimation fits a plane to "
            f"each point's {k} nearest neighbours, so it needs at least {k + 1}: give more "
            "points (in Python, or lower `k`)"
        )

    tree = cKDTree(p)
    dist, idx = tree.query(p, k=k + 1, workers=-1)  # idx[:, 0] is the point itself
    raw = _one_sheet(p, idx)
    normals, unsure, n_comp = _oriented(p, raw, dist, idx, k, refill=True)
    flipped = float(np.mean(np.einsum("ij,ij->i", normals, raw) < 0))
    report = NormalsReport(k=k, flipped=flipped, unsure=unsure, components=n_comp, n=len(p_all))
    if verbose:
        print(f"jaxrbf: {report.summary()}", file=sys.stderr, flush=True)
    return normals[inverse], report


def orient_normals(points, normals, k: int | None = None) -> np.ndarray:
    """`normals` (n, 3) of the 3-D `points`, each turned (its sign only) so that all agree
    along the surface and point out of each connected component, as `estimate_normals` orients
    its own: for normals that came with a cloud but point either way (an unoriented estimate,
    a soup's faces wound at random). Their directions are kept."""
    from scipy.spatial import cKDTree

    p_all = _check_points(points)
    nrm = np.asarray(normals, dtype=float).reshape(p_all.shape)
    nrm = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
    p, first, inverse = np.unique(p_all, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    k = min(default_k(len(p)) if k is None else int(k), len(p) - 1)
    if k < 3:
        return nrm
    dist, idx = cKDTree(p).query(p, k=k + 1, workers=-1)
    out, _, _ = _oriented(p, nrm[first], dist, idx, k, refill=False)
    sign = np.where(np.einsum("ij,ij->i", out[inverse], nrm) < 0, -1.0, 1.0)
    return nrm * sign[:, None]
