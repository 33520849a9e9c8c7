"""Sharp features (creases) of a 3-D implicit from its gradient and Hessian.

At each candidate point on f = 0 the shape operator of the level set is the Hessian of f
restricted to the tangent plane and divided by |grad f|,

    S = T^T H T / |grad f|,   T = an orthonormal basis (3 x 2) of the plane normal to grad f,

whose eigenvalues are the principal curvatures k1 >= k2 (positive where the surface is convex
with f growing outwards: 1/R on a sphere of radius R) and whose eigenvectors are the principal
directions (Goldman 2005, "Curvature formulas for implicit curves and surfaces", eq. 3.1 / 4.1).
An RBF fit rounds a crease over about one sample spacing, so a crease shows up as a narrow band
of very high curvature across it and low curvature along it: the crease runs along the principal
direction of least |curvature|.

The Hessian comes from JAX (forward-mode derivatives of the model's gradient, one per coordinate),
evaluated in fixed-size jit-compiled chunks (the last one padded), never from finite differences.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Callable
from dataclasses import dataclass, field

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._errors import InputError

__all__ = [
    "Features",
    "FEATURE_FLOOR",
    "FEATURE_FRACTION",
    "FEATURE_QUANTILE",
    "chain_points",
    "default_threshold",
    "principal_curvatures",
    "ridge_points",
    "sharp_features",
    "write_feature_points",
    "write_feature_polylines",
    "add_features_parser",
    "run_features",
]

_CHUNK = 2048  # points per compiled chunk (the model splits it further into its own blocks)

FEATURE_FLOOR = 12.0
"""Smallest default threshold on the sharpness |k|max * diagonal: a feature is sharp only where
its radius of curvature is below 1/12 of the bounding-box diagonal (a sphere scores about 3.5)."""

FEATURE_FRACTION = 0.5
FEATURE_QUANTILE = 0.99
"""Default threshold: FEATURE_FRACTION of the sharpness of the sharpest 1% (its 99th percentile
over all candidates), at least FEATURE_FLOOR. A crease fitted by an RBF is rounded over about one
sample spacing, with a curvature that peaks on the crease line: the rule keeps the band where it
is at least half its peak. (A median + k MAD outlier rule was tried and rejected: on a CAD part
such as the fandisk half the surface lies near a crease or on a tight fillet, the distribution is
not a bulk with outliers, and that rule kept 22 of 19,450 points.)"""

POLYLINE_OUTPUTS_3D = (".csv", ".npz")


@dataclass(frozen=True, eq=False)
class Features:
    """Sharp-feature points of an implicit surface.

    **Fields:**
    - `points`: (k, 3) feature points (on f = 0 when the candidates were projected).
    - `curvature`: (k, 2) principal curvatures (k1, k2) at them, k1 the larger in magnitude.
    - `sharpness`: (k,) |k1| times `length` (dimensionless; compared with `threshold`).
    - `direction`: (k, 3) unit crease directions (principal direction of least |curvature|).
    - `normals`: (k, 3) unit normals grad f / |grad f|.
    - `threshold`: the threshold used. `length`: the length scale (diagonal of the implicit's
      `bounds()`, or of the candidates' bounding box for a callable without bounds).
    - `polylines`: list of (j, 3) chains of feature points (empty unless asked for).
    - `candidates`: number of candidate points examined; `max_sharpness`: the largest sharpness
      among them (tells how far the threshold is from catching anything).
    """

    points: np.ndarray
    curvature: np.ndarray
    sharpness: np.ndarray
    direction: np.ndarray
    normals: np.ndarray
    threshold: float
    length: float
    candidates: int
    max_sharpness: float
    polylines: list[np.ndarray] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.points)


# --------------------------------------------------------------------------- differential geometry


def _grad_fn(implicit: Callable) -> Callable:
    from ._project import value_and_gradient

    return lambda q: value_and_gradient(implicit, q)[1]


@eqx.filter_jit
def _shape_operator(implicit, p):
    """(g, k, dirs): gradient (n, 3), principal curvatures (n, 2) sorted by decreasing |k|, and
    principal directions (n, 2, 3) at a chunk of points."""
    grad = _grad_fn(implicit)
    g = grad(p)
    cols = [
        jax.jvp(grad, (p,), (jnp.broadcast_to(e, p.shape),))[1] for e in jnp.eye(3, dtype=p.dtype)
    ]
    hess = jnp.stack(cols, axis=2)
    hess = 0.5 * (hess + jnp.swapaxes(hess, 1, 2))
    gn = jnp.linalg.norm(g, axis=1, keepdims=True)
    safe = jnp.where(gn > 0, gn, 1.0)
    n = g / safe
    # tangent basis: the coordinate axis least aligned with n, made orthogonal to it
    pick = jnp.where(jnp.abs(n[:, :1]) < 0.9, jnp.array([1.0, 0, 0]), jnp.array([0.0, 1, 0]))
    t1 = pick - jnp.sum(pick * n, axis=1, keepdims=True) * n
    t1 = t1 / jnp.linalg.norm(t1, axis=1, keepdims=True)
    t2 = jnp.cross(n, t1)
    t = jnp.stack([t1, t2], axis=2)  # (n, 3, 2)
    s = jnp.einsum("nia,nij,njb->nab", t, hess, t) / safe[:, :, None]
    k, v = jnp.linalg.eigh(s)  # ascending; v[:, :, i] the i-th eigenvector in the (t1, t2) frame
    order = jnp.argsort(-jnp.abs(k), axis=1)
    k = jnp.take_along_axis(k, order, axis=1)
    v = jnp.take_along_axis(v, order[:, None, :], axis=2)
    dirs = jnp.einsum("nia,nab->nbi", t, v)  # (n, 2, 3)
    k = jnp.where(gn > 0, k, jnp.nan)
    return g, k, dirs


@eqx.filter_jit
def _project_chunk(implicit, p, max_step, steps: int = 6):
    """Newton steps x <- x - f grad f / |grad f|^2 (each at most `max_step` long) onto f = 0;
    points whose final distance estimate exceeds `max_step` go back to where they started."""
    from ._project import _newton_step, value_and_gradient

    def body(_, x):
        f, g = value_and_gradient(implicit, x)
        return _newton_step(x, f, g, 0.0, max_step)

    x = jax.lax.fori_loop(0, steps, body, p)
    f, g = value_and_gradient(implicit, x)
    gn = jnp.linalg.norm(g, axis=1)
    ok = jnp.isfinite(f) & (jnp.abs(f) <= max_step * gn)
    return jnp.where(ok[:, None], x, p)


def _chunked(fn, p: np.ndarray, *args):
    """`fn(p_chunk, *args)` over fixed-size chunks of `p` (the last padded with copies of row 0,
    so every chunk reuses one compilation), joined on the host."""
    outs = None
    for start in range(0, len(p), _CHUNK):
        block = p[start : start + _CHUNK]
        m = len(block)
        if m < _CHUNK:
            block = np.concatenate([block, np.broadcast_to(p[:1], (_CHUNK - m, 3))])
        res = fn(jnp.asarray(block), *args)
        res = res if isinstance(res, tuple) else (res,)
        if outs is None:
            outs = [[] for _ in res]
        for o, r in zip(outs, res, strict=True):
            o.append(np.asarray(r)[:m])
    return tuple(np.concatenate(o) for o in outs)


def _check_implicit(implicit) -> None:
    if not callable(implicit):
        raise InputError(
            f"`implicit` must be a callable mapping (n, 3) points to (n,) values, got {type(implicit).__name__}"
        )
    dim = getattr(implicit, "dim", 3)
    if dim != 3:
        raise InputError(
            f"`implicit` must be a 3-D implicit, got a {dim}-D model: sharp features are found "
            "on surfaces; fit 3-D points"
        )


def _check_points(points, name: str = "points") -> np.ndarray:
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"`{name}` must have shape (n, 3), got {p.shape}")
    bad = int(np.count_nonzero(~np.isfinite(p).all(axis=1)))
    if bad:
        raise InputError(
            f"`{name}` has {bad} rows with NaN or infinite coordinates; drop them first"
        )
    return p


def principal_curvatures(implicit: Callable, points) -> tuple[np.ndarray, np.ndarray]:
    """Principal curvatures and directions of the level sets of a 3-D implicit.

    **Arguments:**
    - `implicit`: a 3-D model or any JAX-traceable callable mapping (n, 3) points to (n,) values.
    - `points`: (n, 3) points (the level set through each point is measured).

    **Returns:** `(k, directions)`: (n, 2) curvatures sorted by decreasing magnitude (1/R on a
    sphere of radius R with f growing outwards) and (n, 2, 3) their unit principal directions.
    """
    _check_implicit(implicit)
    p = _check_points(points)
    if len(p) == 0:
        return np.zeros((0, 2)), np.zeros((0, 2, 3))
    _, k, d = _chunked(lambda q: _shape_operator(implicit, q), p)
    return k, d


# --------------------------------------------------------------------------- detection


def default_threshold(sharpness: np.ndarray) -> float:
    """max(FEATURE_FLOOR, FEATURE_FRACTION * the FEATURE_QUANTILE quantile) of the candidates'
    sharpness: half the peak sharpness of the creases, and a floor so that a smooth surface (a
    sphere scores about 3.5 everywhere) has no features."""
    s = sharpness[np.isfinite(sharpness)]
    if len(s) == 0:
        return FEATURE_FLOOR
    return max(FEATURE_FLOOR, FEATURE_FRACTION * float(np.quantile(s, FEATURE_QUANTILE)))


def sharp_features(
    implicit: Callable,
    points=None,
    *,
    mesh=None,
    threshold: float | None = None,
    resolution: int = 128,
    project: bool = True,
    polylines: bool = False,
    neighbours: int = 8,
    min_chain: int = 4,
) -> Features:
    """Points where the surface f = 0 of a 3-D implicit is sharp: the largest |principal
    curvature| times a length scale (the diagonal of the implicit's `bounds()`, e.g. a model's
    centres' box, or else of the candidates' bounding box) exceeds `threshold`.

    **Arguments:**
    - `implicit`: a 3-D model (`RBFModel`, `PartitionModel`) or any JAX-traceable callable.
    - `points`: (n, 3) candidate points; default: the vertices of `mesh`.
    - `mesh`: a `jaxrbf.io.Mesh` whose vertices are the candidates; default: `polygonize(implicit,
      resolution)`.
    - `threshold`: on the dimensionless sharpness |k|max * diagonal (a radius of curvature below
      diagonal / threshold is sharp). Default: `default_threshold` (half the 99th percentile of
      the candidates' sharpness, at least `FEATURE_FLOOR`).
    - `resolution`: marching-cubes resolution when the mesh is made here.
    - `project`: Newton-project the candidates onto f = 0 first (a marching-cubes vertex lies up
      to a cell off the surface, where the level set through it is a different one).
    - `polylines`: also chain the feature points into polylines (k-NN graph, minimum spanning
      tree, split at branch points); `neighbours` nearest neighbours per point, and chains shorter
      than `min_chain` points are dropped.

    **Returns:** a `Features`.
    """
    _check_implicit(implicit)
    if points is None:
        if mesh is None:
            from ._polygonize import polygonize

            mesh = polygonize(implicit, resolution=resolution)
        points = mesh.vertices
        spacing = _mean_edge(mesh)
    else:
        spacing = None
    p = _check_points(points)
    if len(p) < 2:
        raise InputError(f"need at least 2 candidate points, got {len(p)}")
    length = _length_scale(implicit, p)
    if not length > 0:
        raise InputError("all candidate points are the same point")
    if spacing is None:
        spacing = _mean_spacing(p)
    if project:
        (p,) = _chunked(lambda q: _project_chunk(implicit, q, jnp.asarray(2.0 * spacing)), p)
    g, k, dirs = _chunked(lambda q: _shape_operator(implicit, q), p)
    sharp = np.abs(k[:, 0]) * length
    if threshold is None:
        threshold = default_threshold(sharp)
    threshold = float(threshold)
    if not (np.isfinite(threshold) and threshold > 0):
        raise InputError(f"`threshold` must be a positive number, got {threshold}")
    keep = np.isfinite(sharp) & (sharp > threshold)
    gn = np.linalg.norm(g[keep], axis=1, keepdims=True)
    out = Features(
        points=p[keep],
        curvature=k[keep],
        sharpness=sharp[keep],
        direction=dirs[keep, 1],
        normals=g[keep] / np.where(gn > 0, gn, 1.0),
        threshold=threshold,
        length=length,
        candidates=len(p),
        max_sharpness=float(np.nanmax(sharp)) if np.isfinite(sharp).any() else float("nan"),
    )
    if polylines and len(out) >= 2:
        ridge = ridge_points(out.points, out.sharpness, out.direction, radius=3.0 * spacing)
        chains = chain_points(out.points[ridge], neighbours=neighbours, radius=3.0 * spacing)
        object.__setattr__(out, "polylines", [c for c in chains if len(c) >= min_chain])
    return out


def _length_scale(implicit, p: np.ndarray) -> float:
    """The diagonal of the implicit's `bounds()` where it has them (a model: its centres' box),
    else of the candidates' bounding box."""
    bounds = getattr(implicit, "bounds", None)
    if callable(bounds):
        try:
            lo, hi = (np.asarray(b, dtype=float) for b in bounds())
            diag = float(np.linalg.norm(hi - lo))
            if np.isfinite(diag) and diag > 0:
                return diag
        except (TypeError, ValueError, NotImplementedError):
            pass
    return float(np.linalg.norm(np.ptp(p, axis=0)))


def _mean_edge(mesh) -> float:
    v = np.asarray(mesh.vertices, dtype=float)
    f = np.asarray(mesh.faces)
    if len(f) == 0:
        return _mean_spacing(v)
    e = v[f] - v[np.roll(f, 1, axis=1)]
    return float(np.mean(np.linalg.norm(e, axis=2)))


def _mean_spacing(p: np.ndarray) -> float:
    from scipy.spatial import cKDTree

    d, _ = cKDTree(p).query(p, k=2)
    return float(np.mean(d[:, 1])) or 1.0


# --------------------------------------------------------------------------- chaining


def ridge_points(points, sharpness, direction, radius: float) -> np.ndarray:
    """Indices of the points on the crease line: a point is kept unless a neighbour within
    `radius`, lying across the crease from it (offset within 60 degrees of the normal plane of
    `direction`), is sharper (non-maximum suppression across the crease; the band of feature
    points an RBF leaves around a crease becomes one line of points)."""
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=float)
    keep = np.ones(len(p), dtype=bool)
    for i, nb in enumerate(cKDTree(p).query_ball_point(p, radius)):
        nb = np.asarray([j for j in nb if j != i], dtype=int)
        if len(nb) == 0:
            continue
        off = p[nb] - p[i]
        along = np.abs(off @ direction[i])
        across = along <= 0.5 * np.linalg.norm(off, axis=1)
        if np.any(across & (sharpness[nb] > sharpness[i])):
            keep[i] = False
    return np.flatnonzero(keep)


def chain_points(
    points: np.ndarray, neighbours: int = 8, radius: float | None = None
) -> list[np.ndarray]:
    """Chain scattered feature points into polylines: a k-nearest-neighbour graph (edges longer
    than `radius` dropped), its minimum spanning forest, and the forest cut into maximal paths
    between nodes whose degree is not 2 (ends and branch points).

    **Returns:** a list of (j, 3) arrays, each a chain of points in order.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import minimum_spanning_tree
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=float)
    n = len(p)
    if n < 2:
        return []
    kk = min(neighbours + 1, n)
    d, idx = cKDTree(p).query(p, k=kk)
    rows = np.repeat(np.arange(n), kk - 1)
    cols = idx[:, 1:].ravel()
    w = d[:, 1:].ravel()
    ok = np.isfinite(w) & (w > 0)
    if radius is not None:
        ok &= w <= radius
    graph = coo_matrix((w[ok], (rows[ok], cols[ok])), shape=(n, n)).tocsr()
    graph = graph.maximum(graph.T)
    tree = minimum_spanning_tree(graph).tocoo()
    adj: list[list[int]] = [[] for _ in range(n)]
    for a, b in zip(tree.row.tolist(), tree.col.tolist(), strict=True):
        adj[a].append(b)
        adj[b].append(a)
    deg = np.array([len(a) for a in adj])
    seen: set[tuple[int, int]] = set()
    chains = []
    for s in np.flatnonzero(deg != 2).tolist():
        for nxt in adj[s]:
            if (s, nxt) in seen:
                continue
            path = [s]
            prev, cur = s, nxt
            seen.add((prev, cur))
            seen.add((cur, prev))
            while True:
                path.append(cur)
                if deg[cur] != 2:
                    break
                step = adj[cur][0] if adj[cur][0] != prev else adj[cur][1]
                prev, cur = cur, step
                seen.add((prev, cur))
                seen.add((cur, prev))
            chains.append(p[path])
    return chains


# --------------------------------------------------------------------------- output


def write_feature_points(path, features: Features) -> None:
    """Write the feature points through `jaxrbf.io.write_points` (.ply, .xyz or .npz), atomically."""
    from .io import write_points

    if len(features) == 0:
        raise InputError(
            f"no feature points to write to '{os.fspath(path)}': none above the threshold "
            f"{features.threshold:.3g}; lower it"
        )
    write_points(path, features.points)


def write_feature_polylines(path, polylines: list[np.ndarray]) -> None:
    """Write 3-D polylines atomically: `.csv` (header `polyline,x,y,z`, one row per point) or
    `.npz` (arrays `polyline_0`, `polyline_1`, ... of shape (j, 3)). (`jaxrbf.io.write_polylines`
    holds 2-D curves only.)"""
    from .io import save_curves

    p = os.fspath(path)
    ext = os.path.splitext(p)[1].lower()
    if ext not in POLYLINE_OUTPUTS_3D:
        raise InputError(
            f"cannot write polylines to '{p}' ('{ext}'); supported: {', '.join(POLYLINE_OUTPUTS_3D)}"
        )
    curves = [_check_points(c, f"polylines[{i}]") for i, c in enumerate(polylines)]
    save_curves(p, ext, curves, "polyline", 3)


# --------------------------------------------------------------------------- command line


def add_features_parser(subparsers) -> argparse.ArgumentParser:
    """Add `jaxrbf features MODEL.npz -o creases.ply [--threshold T] [--resolution R]
    [--polylines out.csv]` to an argparse subparsers object; returns the new parser."""
    p = subparsers.add_parser(
        "features",
        help="detect sharp features (creases) of a saved 3-D model",
        description="Mesh a saved model, measure principal curvatures from its Hessian at the "
        "vertices and write the sharp points (and optionally chained polylines).",
    )
    p.add_argument("model", help="a model saved by `jaxrbf fit` (.npz)")
    p.add_argument("-o", "--output", required=True, help="feature points: .ply, .xyz or .npz")
    p.add_argument(
        "--threshold",
        type=float,
        help="sharpness |k|max x diagonal above which a point is a feature (default: "
        f"max({FEATURE_FLOOR:g}, {FEATURE_FRACTION:g} x the 99th percentile))",
    )
    p.add_argument("--resolution", type=int, default=128, help="marching-cubes resolution (128)")
    p.add_argument("--polylines", help="also write chained feature polylines: .csv or .npz")
    p.add_argument("-q", "--quiet", action="store_true", help="no summary on stderr")
    return p


def run_features(args) -> int:
    """Run the `features` subcommand; returns the exit status (0). Errors raise `InputError`."""
    import sys

    from ._serialize import load
    from .io import POINT_OUTPUTS

    out_ext = os.path.splitext(args.output)[1].lower()
    if out_ext not in POINT_OUTPUTS:
        raise InputError(
            f"cannot write feature points to '{args.output}'; supported: {', '.join(POINT_OUTPUTS)}"
        )
    if args.polylines and os.path.splitext(args.polylines)[1].lower() not in POLYLINE_OUTPUTS_3D:
        raise InputError(
            f"cannot write polylines to '{args.polylines}'; supported: {', '.join(POLYLINE_OUTPUTS_3D)}"
        )
    if args.resolution is not None and args.resolution < 4:
        raise InputError(f"--resolution must be at least 4, got {args.resolution}")
    model = load(args.model)
    feats = sharp_features(
        model,
        threshold=args.threshold,
        resolution=args.resolution,
        polylines=bool(args.polylines),
    )
    if len(feats) == 0:
        raise InputError(
            f"no sharp features: none of the {feats.candidates:,} surface points has a sharpness "
            f"above {feats.threshold:.3g} (the sharpest: {feats.max_sharpness:.3g}); lower "
            "--threshold or raise --resolution; nothing written"
        )
    write_feature_points(args.output, feats)
    if args.polylines:
        write_feature_polylines(args.polylines, feats.polylines)
    if not args.quiet:
        print(
            f"features: {len(feats):,} of {feats.candidates:,} points above sharpness "
            f"{feats.threshold:.3g}, {len(feats.polylines)} polylines",
            file=sys.stderr,
        )
    return 0
