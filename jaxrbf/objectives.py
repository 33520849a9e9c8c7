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

Kernels that decay (Gaussian, inverse multiquadric) fit over a background (`background=True`,
see `jaxrbf.surface_background`), built from the training samples of each fit, so that no
held-out sample leaks into it; `jaxrbf.tune` asks for it with those kernels.

`points` and `normals` are host data here (numpy; the split, the spacing and the offset caps are
computed from them on the host); to differentiate with respect to points or normals, build
`jaxrbf.surface_constraints` and call `jaxrbf.fit` yourself.

Precision: float64 throughout (the solves of `jaxrbf.fit`).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

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
    "held_out_data",
    "held_out_value_and_grad",
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
    fq = side = None
    if probes is not None and len(probes[0]):
        fq, side = model(jnp.asarray(probes[0])), jnp.asarray(probes[1])
    dist, mis = pointwise_errors(model(p), model.gradient(p), normals, length)
    return _error_terms(dist, mis, length, fq, side, residuals)


def _gradient_norm(g):
    return jnp.sqrt(jnp.sum(g * g, axis=-1) + 1e-300)


def first_order_distance(f, g):
    """|f| / |grad f| from values `f` (...) and gradients `g` (..., d): the first-order distance
    to the zero set, in the points' units."""
    return jnp.abs(f) / _gradient_norm(g)


def pointwise_errors(f, g, normals, length):
    """The two terms of `surface_error` at each point, unaveraged: (|f| / |grad f| / `length`,
    max(0, 1 - cos(grad f, n))), from values `f` (...), gradients `g` (..., d) and `normals`
    broadcastable to `g` (the coordinate axis last)."""
    nrm = jnp.asarray(normals, dtype=float)
    nrm = nrm / jnp.linalg.norm(nrm, axis=-1, keepdims=True)
    dist = first_order_distance(f, g) / length
    mis = jnp.maximum(1.0 - jnp.sum(g * nrm, axis=-1) / _gradient_norm(g), 0.0)
    return dist, mis


def _error_terms(dist, mis, length, fq=None, side=None, residuals: bool = False):
    """`surface_error` from the per-point terms `dist`, `mis` of `pointwise_errors` (and `fq`,
    the values at the probes, on their `side`)."""
    n = dist.shape[0]
    terms = [dist / n, mis / n]
    if fq is not None and fq.shape[0]:
        wrong = jax.nn.sigmoid(-side * fq / (0.5 * length))
        terms.append(SIGN_WEIGHT * wrong / fq.shape[0])
    if residuals:
        return jnp.sqrt(jnp.concatenate(terms) + 1e-30)
    return sum(jnp.sum(t) for t in terms)


def capped_constraints(points, normals, offset):
    """`surface_constraints` of surface samples at `offset` (may be traced), each off-surface
    point's offset capped where the Carr test fails and at `OFFSET_LIMIT` of the diagonal
    (`offset_caps`, host): the constraints every objective and tuned fit uses."""
    from ._constraints import offset_caps, surface_constraints
    from ._prepare import diagonal

    p = np.asarray(points, dtype=float)
    return surface_constraints(
        p, normals, offset, offset_caps(p, normals, OFFSET_LIMIT * diagonal(p))
    )


def _background_of(points, normals, background: bool):
    """The background model of a fit of these surface samples (host), or None."""
    if not background:
        return None
    from ._background import surface_background

    return surface_background(points, normals)


def _fit_surface_model(
    points, normals, *, kernel, offset, radius, smoothing, degree, solver, background=False
):
    """The dense, differentiable fit of surface samples (over their background when
    `background`); returns (model, ok)."""
    from ._difffit import solve_dense
    from ._fit import RESIDUAL_TOL
    from .kernels import make_kernel

    c = capped_constraints(points, normals, offset)
    kern = make_kernel(kernel, radius)
    bg = _background_of(points, normals, background)
    model, residual, finite = solve_dense(c.points, c.values, kern, degree, smoothing, solver, bg)
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
    background: bool = False,
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
    - `background`: fit over `jaxrbf.surface_background` of the training samples.

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
        background=background,
    )
    probes = sign_probes(p, nrm) if use_probes else None
    err = surface_error(
        model, p[test], nrm[test], point_spacing(p), probes=probes, residuals=residuals
    )
    return jnp.where(ok, err, jnp.inf)


class HeldOutData(NamedTuple):
    """The host-side part of `held_out_error`, computed once (`held_out_data`) for
    `held_out_value_and_grad`: the training samples with their off-surface points' origins,
    normals and offset caps (those with a NaN cap left out), the held-out samples, the length
    unit, the sign probes (empty unless asked for), and the background of the training samples
    (None, or a model) with its values and gradients at the held-out samples and its values at
    the probes (zeros without one)."""

    surface: Array
    out_p: Array
    out_n: Array
    out_cap: Array
    in_p: Array
    in_n: Array
    in_cap: Array
    test_p: Array
    test_n: Array
    length: Array
    probe_q: Array
    probe_side: Array
    background: object
    bg_test: Array
    bg_test_grad: Array
    bg_probe: Array


def held_out_data(
    points,
    normals,
    *,
    holdout: float = 0.2,
    seed: int = 0,
    test=None,
    use_probes: bool = False,
    background: bool = False,
) -> HeldOutData:
    """The host-side preparation of `held_out_error` (split, offset caps, point spacing, probes,
    the background of the training samples), as arrays for `held_out_value_and_grad`. Host
    (KD-trees)."""
    from ._constraints import checked_samples, offset_caps
    from ._prepare import diagonal

    p, nrm = checked_samples(points, normals)
    if test is None:
        train, test = split_samples(len(p), holdout, seed)
    else:
        test = np.asarray(test)
        train = np.setdiff1d(np.arange(len(p)), test)
    pt, nt = p[train], nrm[train]
    caps = offset_caps(pt, nt, OFFSET_LIMIT * diagonal(pt))
    ko, ki = np.isfinite(caps[0]), np.isfinite(caps[1])
    if use_probes:
        q, side = sign_probes(p, nrm)
    else:
        q, side = np.zeros((0, p.shape[1])), np.zeros(0)
    a = functools.partial(jnp.asarray, dtype=float)
    bg = _background_of(pt, nt, background)
    if bg is None:
        g_test, dg_test, g_probe = np.zeros(len(test)), np.zeros((len(test), p.shape[1])), 0 * side
    else:
        g_test, dg_test = bg.value_and_gradient(a(p[test]))
        g_probe = bg(a(q)) if len(q) else 0 * side
    return HeldOutData(
        a(pt),
        a(pt[ko]),
        a(nt[ko]),
        a(caps[0][ko]),
        a(pt[ki]),
        a(nt[ki]),
        a(caps[1][ki]),
        a(p[test]),
        a(nrm[test]),
        a(point_spacing(p)),
        a(q),
        a(side),
        bg,
        a(g_test),
        a(dg_test),
        a(g_probe),
    )


def _theta(y, lo, hi, base):
    v = dict(base)
    for k in y:
        v[k] = jnp.exp(jnp.clip(y[k], lo[k], hi[k]))
    return v


def _held_out_parts(th, data: HeldOutData, kernel: str, shift=None, scale=None):
    """Normalised constraint points, values, kernel and smoothing of the held-out fit at the
    parameters `th` (the unit-box transform from the points, as constants, unless given)."""
    from ._difffit import unit_box
    from .kernels import kernel_class, make_kernel

    d = data
    do = jnp.minimum(th["offset"], d.out_cap)
    di = jnp.minimum(th["offset"], d.in_cap)
    x = jnp.concatenate([d.surface, d.out_p + do[:, None] * d.out_n, d.in_p - di[:, None] * d.in_n])
    h = jnp.concatenate([jnp.zeros(d.surface.shape[0]), do, -di])
    if d.background is not None:
        h = h - d.background(x)
    if shift is None:
        shift, scale = unit_box(x)
    cls = kernel_class(kernel)
    kern = make_kernel(kernel, th["radius"] if cls.has_radius else None)
    sm = th["smoothing"] / scale**cls.homogeneity
    return (x - shift) / scale, h, kern.scaled(1.0 / scale), sm, shift, scale


@functools.partial(jax.jit, static_argnames=("kernel", "degree"))
def _held_out_system(y, lo, hi, base, data, *, kernel, degree):
    from ._system import saddle_matrix

    xn, h, kn, sm, shift, scale = _held_out_parts(_theta(y, lo, hi, base), data, kernel)
    b = saddle_matrix(kn, xn, degree, sm)
    return b, jnp.concatenate([h, jnp.zeros(b.shape[0] - h.shape[0])]), shift, scale


# Compiled apart from the kernel's matrix: shared by every kernel fitted to the same samples.
@jax.jit
def _lu_solve_checked(b, rhs):
    from ._fit import RESIDUAL_TOL

    lu = jax.scipy.linalg.lu_factor(b)
    z = jax.scipy.linalg.lu_solve(lu, rhs)
    residual = jnp.max(jnp.abs(b @ z - rhs)) / jnp.maximum(jnp.max(jnp.abs(rhs)), 1e-300)
    return lu, z, jnp.all(jnp.isfinite(z)) & (residual <= RESIDUAL_TOL)


def _held_out_error_at(z, y, lo, hi, base, data, shift, scale, kernel, degree):
    """`surface_error` of the held-out fit with weights and coefficients `z` at log-parameters
    `y`, with f and grad f at the held-out samples written out (as `RBFModel` computes them, but
    with the closed-form `_dphi_dr2`): a small program to compile and differentiate. Returns
    (error, the error of each held-out sample: distance + misalignment, whose mean is the error
    without probes)."""
    from ._model import pairwise_sq, poly_basis

    n = data.surface.shape[0] + data.out_p.shape[0] + data.in_p.shape[0]
    xn, _, kn, _, _, _ = _held_out_parts(_theta(y, lo, hi, base), data, kernel, shift, scale)
    w, a = z[:n], z[n:]
    tn = (data.test_p - shift) / scale
    r2 = pairwise_sq(tn, xn)
    f = kn.from_r2(r2) @ w + poly_basis(tn, degree) @ a + data.bg_test
    d = _dphi_dr2(kn, r2)
    g = 2.0 * (tn * (d @ w)[:, None] - d @ (w[:, None] * xn))
    if degree >= 1:
        g = g + a[1:]
    fq = None
    if data.probe_q.shape[0]:
        qn = (data.probe_q - shift) / scale
        fq = kn.from_r2(pairwise_sq(qn, xn)) @ w + poly_basis(qn, degree) @ a + data.bg_probe
    g = g / scale + data.bg_test_grad
    dist, mis = pointwise_errors(f, g, data.test_n, data.length)
    return _error_terms(dist, mis, data.length, fq, data.probe_side), dist + mis


@functools.partial(jax.jit, static_argnames=("kernel", "degree"))
def _held_out_error_only(z, y, lo, hi, base, data, shift, scale, *, kernel, degree):
    return _held_out_error_at(z, y, lo, hi, base, data, shift, scale, kernel, degree)


@functools.partial(jax.jit, static_argnames=("kernel", "degree"))
def _held_out_error_and_adjoint(z, lu, y, lo, hi, base, data, shift, scale, *, kernel, degree):
    def error(z):
        return _held_out_error_at(z, y, lo, hi, base, data, shift, scale, kernel, degree)

    (e, per), gz = jax.value_and_grad(error, has_aux=True)(z)
    return e, per, jax.scipy.linalg.lu_solve(lu, gz, trans=1)


def _dphi_dr2(kern, r2):
    """d phi / d(r^2) of `kern`, elementwise: closed forms for the kernels of
    `jaxrbf.kernels` (measured: XLA compiles the forward-mode derivative of Wendland's
    function, through its clip and safe square root, to a pass about 8x slower), forward mode
    for any other."""
    name = getattr(kern, "name", None)
    pos = r2 > 0
    if name in ("gaussian", "multiquadric", "inverse-multiquadric", "wendland"):
        rr = kern.radius**2
        u = 1.0 + r2 / rr
        if name == "gaussian":
            return -jnp.exp(-r2 / rr) / rr
        if name == "multiquadric":
            return -0.5 / (rr * jnp.sqrt(u))
        if name == "inverse-multiquadric":
            return -0.5 / (rr * u * jnp.sqrt(u))
        s = jnp.maximum(1.0 - jnp.sqrt(jnp.maximum(r2, 1e-300)) / kern.radius, 0.0)
        return -10.0 * s * s * s / rr
    if name == "cubic":
        return 1.5 * jnp.sqrt(jnp.maximum(r2, 1e-300))
    if name == "thin-plate":
        return jnp.where(pos, 0.5 * (jnp.log(jnp.where(pos, r2, 1.0)) + 1.0), 0.0)
    if name == "linear":
        return jnp.where(pos, -0.5 / jnp.sqrt(jnp.where(pos, r2, 1.0)), 0.0)
    return jax.jvp(kern.from_r2, (r2,), (jnp.ones_like(r2),))[1]


@functools.partial(jax.jit, static_argnames=("kernel", "degree", "name"))
def _held_out_coupling(z, lam, y, lo, hi, base, data, shift, scale, *, kernel, degree, name):
    # d/dy[name] of E(z, y) - lam^T (B(y) z - [h(y); 0]) at fixed lam and z. The kernel block's
    # term, sum_ij lam_i z_j phi(r_ij^2), is differentiated by hand in one elementwise pass that
    # XLA fuses into the sum (no n x n tangent is stored): d(r_ij^2) from the points' tangents
    # and, for the radius R (every kernel with one is a function of r^2 / R^2),
    # d phi = -2 r^2 phi'(r^2) d(log R). The rest (held-out error, polynomial block, values,
    # smoothing) is small and differentiated by forward mode.
    from ._model import pairwise_sq, poly_basis

    n = data.surface.shape[0] + data.out_p.shape[0] + data.in_p.shape[0]
    w, a, lw, la = z[:n], z[n:], lam[:n], lam[n:]

    def parts(v):
        return _held_out_parts(
            _theta(dict(y, **{name: v}), lo, hi, base), data, kernel, shift, scale
        )

    def rest(v):
        xn, h, _, sm, _, _ = parts(v)
        pb = poly_basis(xn, degree)
        coupling = (
            sm * jnp.dot(lw, w) + jnp.dot(lw, pb @ a) + jnp.dot(la, pb.T @ w) - jnp.dot(lw, h)
        )
        yy = dict(y, **{name: v})
        err = _held_out_error_at(z, yy, lo, hi, base, data, shift, scale, kernel, degree)[0]
        return err - coupling

    v0, t0 = y[name], jnp.ones_like(y[name])
    d_rest = jax.jvp(rest, (v0,), (t0,))[1]
    xn, _, kn, _, _, _ = parts(v0)
    r2 = pairwise_sq(xn, xn)
    if name == "offset":
        dx = jax.jvp(lambda v: parts(v)[0], (v0,), (t0,))[1]
        dr2 = 0.0
        for k in range(xn.shape[1]):
            dr2 = dr2 + 2.0 * (xn[:, k, None] - xn[None, :, k]) * (dx[:, k, None] - dx[None, :, k])
    elif name == "radius" and hasattr(kn, "radius"):
        dlog = jax.jvp(lambda v: jnp.log(parts(v)[2].radius), (v0,), (t0,))[1]
        dr2 = -2.0 * r2 * dlog
    else:
        return d_rest
    d_kernel = jnp.sum(lw[:, None] * _dphi_dr2(kn, r2) * dr2 * w[None, :])
    return d_rest - d_kernel


def held_out_value_and_grad(
    y,
    lo,
    hi,
    base,
    data: HeldOutData,
    *,
    kernel: str,
    degree: int = 1,
    gradient: bool = True,
    pointwise: bool = False,
):
    """`held_out_error` (with `solver="lu"`) and its gradient with respect to log-parameters,
    from a few compiled functions cached across calls (same kernel, degree and shapes).

    **Arguments:**
    - `y`: dict of log-parameters (names among `offset`, `radius`, `smoothing`); each parameter is
      exp(clip(y[k], lo[k], hi[k])).
    - `lo`, `hi`: dicts of bounds on y (same keys). `base`: dict of all three parameters' values
      (those not in `y` are held there; the radius is ignored for kernels without one).
    - `data`: from `held_out_data`. `kernel` (a name), `degree`: as for `jaxrbf.fit`.
    - `gradient`: False skips the gradient (then it is zero): the value alone costs one fit.
    - `pointwise`: also return the error of each held-out sample (distance + misalignment; the
      value is their mean when there are no probes), for tests of significance (`jaxrbf.tune`).

    **Returns:** (value, gradient dict like `y`, ok), JAX arrays: inf and a zero gradient where
    the fit fails; with `pointwise`, (value, gradient, ok, errors).

    The gradient is the adjoint one: one LU factorisation of B serves the fit (B z = [h; 0]) and
    the adjoint (B^T lam = dE/dz), and dE/dy = (partial E / partial y) at fixed z minus
    d(lam^T (B z - [h; 0])) / dy at fixed lam and z: per parameter one fused elementwise pass over
    the kernel matrix, no n x n tangent matrix and no further solve (tests/test_tune.py checks it
    against forward mode through `held_out_error`)."""
    y = {k: jnp.asarray(v, dtype=float) for k, v in y.items()}
    args = (lo, hi, base, data)
    b, rhs, shift, scale = _held_out_system(y, *args, kernel=kernel, degree=degree)
    lu, z, ok = _lu_solve_checked(b, rhs)
    del b
    if not gradient:
        e, per = _held_out_error_only(z, y, *args, shift, scale, kernel=kernel, degree=degree)
        grad = {k: jnp.zeros_like(v) for k, v in y.items()}
    else:
        e, per, lam = _held_out_error_and_adjoint(
            z, lu, y, *args, shift, scale, kernel=kernel, degree=degree
        )
        grad = _held_out_gradient(z, lam, y, args, shift, scale, ok, kernel, degree)
    out = (jnp.where(ok, e, jnp.inf), grad, ok)
    return out + (jnp.where(ok, per, jnp.inf),) if pointwise else out


def _held_out_gradient(z, lam, y, args, shift, scale, ok, kernel, degree):
    grad = {}
    for k in y:
        gk = _held_out_coupling(
            z, lam, y, *args, shift, scale, kernel=kernel, degree=degree, name=k
        )
        grad[k] = jnp.where(ok, gk, 0.0)
    return grad


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
    background: bool = False,
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
            background=background,
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
    background: bool = False,
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
    - `background` (surface form): fit over `jaxrbf.surface_background` of the samples (built
      from all of them: each left-out constraint's own sample may be in its 1,000-sample
      subsample, so the errors are slightly optimistic there).

    **Returns:** the root mean square of the relative errors (or, with `residuals=True`, the
    errors divided by sqrt(n)).
    """
    from ._difffit import unit_box
    from ._system import saddle_matrix
    from .kernels import make_kernel

    if normals is not None:
        if offset is None:
            raise InputError("`offset` is needed with `normals` (the surface form)")
        c = capped_constraints(points, normals, offset)
        x, h, unit = c.points, c.values, jnp.asarray(offset, dtype=float)
        bg = _background_of(points, normals, background)
        if bg is not None:
            h = h - bg(x)
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
