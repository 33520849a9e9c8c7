"""Objectives for choosing the offset d, the kernel radius and the smoothing of a surface fit.

Each is a plain function of the surface samples and the parameters, differentiable with respect
to `offset`, `radius` and `smoothing` (pass JAX scalars and take `jax.grad`), and they share one
signature, so any of them (or your own with the same signature) can be given to `jaxrbf.tune`:

    objective(points, normals, *, kernel, offset, radius, smoothing, degree) -> scalar

- `held_out_error`: fit on a subset of the surface samples, then measure on the rest how far they
  are from the zero set (|f| / |grad f|, a first-order distance, in units of the point spacing) and
  how far the normals are from the fit's (1 - cos(grad f, n)). The default objective of `tune`.
- `kfold_error`: the same averaged over k disjoint held-out folds (k fits).
- `loocv_error`: Rippa's (1999) closed-form leave-one-out error of the dense system: the error
  at constraint i of the fit without it is e_i = c_i / (B^-1)_ii, for c = B^-1 [h; 0]. One
  inverse instead of n fits.

`points` and `normals` are host data here (numpy; the split, the spacing and the offset caps are
computed from them on the host); to differentiate with respect to points or normals, build
`jaxrbf.surface_constraints` and call `jaxrbf.fit` yourself.

Precision: float64 throughout (the solves of `jaxrbf.fit`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ._errors import InputError

__all__ = [
    "surface_error",
    "held_out_error",
    "kfold_error",
    "loocv_error",
    "point_spacing",
    "sign_probes",
    "split_samples",
    "OFFSET_LIMIT",
]

#: Offsets are clipped per point to the largest one (at most this fraction of the bounding-box
#: diagonal) whose off-surface point stays nearer its own origin than any other sample.
OFFSET_LIMIT = 0.1


def point_spacing(points) -> float:
    """Median distance from each point to its nearest neighbour (host, KD-tree)."""
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=float)
    dist, _ = cKDTree(p).query(p, k=2, workers=-1)
    return float(np.median(dist[:, 1]))


def split_samples(n: int, holdout: float = 0.2, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(train, test) index arrays: a random `holdout` fraction of `range(n)` is held out."""
    if not 0 < holdout < 1:
        raise InputError(f"`holdout` must be a fraction in (0, 1), got {holdout!r}")
    perm = np.random.default_rng(seed).permutation(n)
    k = max(1, int(round(holdout * n)))
    return np.sort(perm[k:]), np.sort(perm[:k])


#: Weight of the probes' sign term in `surface_error` (a fraction of probes on the wrong side
#: is a spurious sheet of surface: it costs far more than a small offset of the true one).
SIGN_WEIGHT = 10.0


def sign_probes(points, normals, count: int = 400, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points of the bounding box (grown by 5%) at least 3 point spacings from every sample, with
    the side they lie on (+1 outside, -1 inside) by a vote of their 5 nearest samples' normals
    (sign of (x - p) . n). Far from the samples a fit should have that sign: where it does not,
    its zero set has a spurious sheet that held-out samples on the surface cannot see. Host."""
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=float)
    nrm = np.asarray(normals, dtype=float)
    lo, hi = p.min(axis=0), p.max(axis=0)
    pad = 0.05 * (hi - lo)
    rng = np.random.default_rng(seed)
    cand = rng.uniform(lo - pad, hi + pad, size=(20 * count, p.shape[1]))
    tree = cKDTree(p)
    dist, idx = tree.query(cand, k=5, workers=-1)
    far = dist[:, 0] > 3 * point_spacing(p)
    votes = np.sum(np.sign(np.einsum("ikd,ikd->ik", cand[:, None] - p[idx], nrm[idx])), axis=1)
    keep = far & (np.abs(votes) >= 3)
    return cand[keep][:count], np.sign(votes[keep][:count])


def surface_error(model, points, normals, length, *, probes=None, residuals: bool = False) -> Array:
    """How well `model`'s zero set passes through `points` with `normals`.

    mean(|f| / |grad f|) / length + mean(1 - cos(grad f, n)): the first-order distance of each
    point from the zero set in units of `length` (use the point spacing), plus the normals'
    misalignment; plus, with `probes` = (x, side) from `sign_probes`, `SIGN_WEIGHT` x the
    (smoothed) fraction of probes where f has the wrong sign, sigmoid(-side f / (length / 2)).
    With `residuals=True`, the vector whose squares sum to that value (for least-squares solvers
    such as Levenberg-Marquardt)."""
    p = jnp.asarray(points, dtype=float)
    nrm = jnp.asarray(normals, dtype=float)
    nrm = nrm / jnp.linalg.norm(nrm, axis=1, keepdims=True)
    f = model(p)
    g = model.gradient(p)
    gn = jnp.sqrt(jnp.sum(g * g, axis=1) + 1e-300)
    dist = jnp.abs(f) / gn / length
    mis = 1.0 - jnp.sum(g * nrm, axis=1) / gn
    n = p.shape[0]
    terms = [dist / n, jnp.maximum(mis, 0.0) / n]
    if probes is not None:
        q, side = probes
        if len(q):
            wrong = jax.nn.sigmoid(-jnp.asarray(side) * model(jnp.asarray(q)) / (0.5 * length))
            terms.append(SIGN_WEIGHT * wrong / len(q))
    if residuals:
        return jnp.sqrt(jnp.concatenate(terms) + 1e-30)
    return sum(jnp.sum(t) for t in terms)


def _fit_surface_model(points, normals, *, kernel, offset, radius, smoothing, degree, solver):
    """The dense, differentiable fit of surface samples; returns (model, ok)."""
    from ._constraints import offset_caps, surface_constraints
    from ._difffit import solve_dense
    from ._fit import RESIDUAL_TOL
    from ._prepare import diagonal
    from .kernels import make_kernel

    p = np.asarray(points, dtype=float)
    caps = offset_caps(p, normals, OFFSET_LIMIT * diagonal(p))
    c = surface_constraints(p, normals, offset, caps)
    kern = make_kernel(kernel, radius)
    model, residual, finite = solve_dense(c.points, c.values, kern, degree, smoothing, solver)
    return model, finite & (residual <= RESIDUAL_TOL)


def held_out_error(
    points,
    normals,
    *,
    kernel="cubic",
    offset,
    radius=None,
    smoothing=0.0,
    degree: int = 1,
    holdout: float = 0.2,
    seed: int = 0,
    test=None,
    solver: str = "lu",
    use_probes: bool = False,
    residuals: bool = False,
) -> Array:
    """Fit on the samples not held out, and measure `surface_error` on the held-out ones.

    **Arguments:**
    - `points`, `normals`: (n, d) surface samples and outward normals (host arrays).
    - `kernel`, `radius` (kernels with one), `smoothing`, `degree`: as for `jaxrbf.fit`, in the
      points' units; `offset`: d in the points' units (clipped per point, see `OFFSET_LIMIT`).
    - `holdout`, `seed`: the random fraction held out; or `test`, explicit held-out indices.
    - `solver`: `lu` (default) or `cholesky`.
    - `use_probes`: add the sign term of `sign_probes` (see `surface_error`); off by default:
      on spot with the Gaussian kernel it moved the optimum to a worse Chamfer distance.
    - `residuals`: return the residual vector instead of the scalar (see `surface_error`).

    **Returns:** a scalar (0 is perfect; the distance term is in units of the point spacing of
    all the samples), `inf` when the fit fails (singular system or residual above 1e-6).
    """
    p = np.asarray(points, dtype=float)
    nrm = np.asarray(normals, dtype=float)
    if test is None:
        train, test = split_samples(len(p), holdout, seed)
    else:
        test = np.asarray(test)
        train = np.setdiff1d(np.arange(len(p)), test)
    model, ok = _fit_surface_model(
        p[train],
        nrm[train],
        kernel=kernel,
        offset=offset,
        radius=radius,
        smoothing=smoothing,
        degree=degree,
        solver=solver,
    )
    probes = sign_probes(p, nrm) if use_probes else None
    err = surface_error(
        model, p[test], nrm[test], point_spacing(p), probes=probes, residuals=residuals
    )
    return jnp.where(ok, err, jnp.inf)


def kfold_error(
    points,
    normals,
    *,
    kernel="cubic",
    offset,
    radius=None,
    smoothing=0.0,
    degree: int = 1,
    k: int = 5,
    seed: int = 0,
    solver: str = "lu",
    residuals: bool = False,
) -> Array:
    """`held_out_error` averaged over `k` disjoint folds (each sample is held out once); k fits.
    Arguments as for `held_out_error`."""
    if int(k) < 2:
        raise InputError(f"`k` must be at least 2 folds, got {k!r}")
    folds = np.array_split(np.random.default_rng(seed).permutation(len(points)), int(k))
    errs = [
        held_out_error(
            points,
            normals,
            kernel=kernel,
            offset=offset,
            radius=radius,
            smoothing=smoothing,
            degree=degree,
            test=np.sort(f),
            solver=solver,
            residuals=residuals,
        )
        for f in folds
    ]
    if residuals:
        return jnp.concatenate(errs) / np.sqrt(len(errs))
    return sum(errs) / len(errs)


def loocv_error(
    points,
    normals=None,
    *,
    values=None,
    kernel="cubic",
    offset=None,
    radius=None,
    smoothing=0.0,
    degree: int = 1,
    residuals: bool = False,
    **_unused,
) -> Array:
    """Rippa's closed-form leave-one-out error of the dense system (Rippa 1999, Adv. Comput.
    Math. 11; Fasshauer ch. 17).

    For B [c; a] = [h; 0] (eq. 6), the fit without constraint i misses h_i by
    e_i = c_i / (B^-1)_ii, so all n leave-one-out errors cost one inverse (O(n^3), about three
    LU factorisations) instead of n fits.

    **Arguments:**
    - Surface form: `points`, `normals` and `offset` (the constraints of `surface_constraints`);
      the errors are divided by the offset, so that they compare across offsets.
    - Data form: `points` and `values` (then `normals` is None); errors divided by max|values|.
    - `kernel`, `radius`, `smoothing`, `degree`: as for `jaxrbf.fit`.

    **Returns:** the root mean square of the relative errors (or, with `residuals=True`, the
    errors divided by sqrt(n)).
    """
    from ._constraints import offset_caps, surface_constraints
    from ._difffit import unit_box
    from ._prepare import diagonal
    from ._system import saddle_matrix
    from .kernels import make_kernel

    if normals is not None:
        if offset is None:
            raise InputError("`offset` is needed with `normals` (the surface form)")
        p = np.asarray(points, dtype=float)
        c = surface_constraints(
            p, normals, offset, offset_caps(p, normals, OFFSET_LIMIT * diagonal(p))
        )
        x, h, unit = c.points, c.values, jnp.asarray(offset, dtype=float)
    else:
        if values is None:
            raise InputError("give `normals` and `offset` (surface form) or `values` (data form)")
        x, h = jnp.asarray(points, dtype=float), jnp.asarray(values, dtype=float)
        unit = jnp.max(jnp.abs(h))
    kern = make_kernel(kernel, radius)
    shift, scale = unit_box(x)
    xn = (x - shift) / scale
    kn = kern.scaled(1.0 / scale)
    sm = jnp.asarray(smoothing, dtype=float) / scale**kern.homogeneity
    n = xn.shape[0]
    b = saddle_matrix(kn, xn, degree, sm)
    inv = jnp.linalg.inv(b)
    coef = inv[:n, :n] @ h
    e = coef / jnp.diagonal(inv)[:n] / unit
    if residuals:
        return e / np.sqrt(n)
    return jnp.sqrt(jnp.mean(e * e))
