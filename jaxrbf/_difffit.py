"""The differentiable path of `fit`: taken when any input is a JAX tracer (`jax.grad`, `jax.jit`,
`jax.vmap`, or an optimistix solve).

**Dense.** Every step is a JAX function of the constraint points, their values, the kernel radius
and the smoothing: the normalising transform (its shift and scale are held constant with
`lax.stop_gradient`; the interpolant, as a function of the user's coordinates, does not depend on
them), the saddle matrix of eq. 8 and `lineax.linear_solve` (LU or Cholesky), which differentiates
the solve itself (x' = B^-1 (h' - B' x), reusing the factorisation): no hand-written adjoint.

**Partition of unity.** The patch layout (which constraints each patch holds, the balls and
blend weights, the evaluation lookup grid, the coarser levels' subsamples) is built on the host
from the points, which must therefore be concrete (not traced), and the local weights are a
differentiable function of the values, the kernel radius and the smoothing (the same batched local
solves as `jaxrbf._partition`, differentiated through `jnp.linalg.solve`); those gradients are
exact. Gradients with respect to the points (and so the offset d) are refused with `InputError`:
the balls and memberships depend on the points through discrete choices, and a gradient that
held them fixed would disagree with the function (measured: the wrong sign for d). Under
`jax.jit` the values' concrete numbers are not needed, but the points must be closed-over
constants.

Precision: float64, as in `jaxrbf._fit` (the saddle systems are ill-conditioned).

Checks. Where the primal values are concrete (`jax.grad` outside `jit`), the residual is checked
as in the host path and a bad solve raises `SolveError`. Under `jit` it cannot be inspected on the
host: the check is compiled in with `equinox.error_if` and fails at run time with the same message.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax._src.core import to_concrete_value

from ._errors import InputError, SolveError
from ._model import RBFModel, n_poly
from .kernels import AbstractKernel, make_kernel


def concrete(x):
    """The concrete (host) value of `x` when JAX has one (an array, or a tracer of `jax.grad`
    outside `jit`), else None."""
    if isinstance(x, jax.core.Tracer):
        v = to_concrete_value(x)
        return None if v is None else np.asarray(v)
    return np.asarray(x)


def _arrays(points, values):
    from ._fit import unpack

    points, values = unpack(points, values)
    x = jnp.asarray(points, dtype=float)
    h = jnp.asarray(values, dtype=float)
    if x.ndim != 2 or x.shape[0] == 0:
        raise InputError(f"`points` must be a non-empty array of shape (n, d), got {x.shape}")
    if h.shape != (x.shape[0],):
        raise InputError(
            f"`values` must have shape ({x.shape[0]},) to match `points`, got {h.shape}"
        )
    return x, h


def unit_box(x):
    """Shift and scale of the unit-box transform, as constants (`stop_gradient`)."""
    xs = lax.stop_gradient(x)
    lo, hi = xs.min(axis=0), xs.max(axis=0)
    return 0.5 * (lo + hi), jnp.max(hi - lo)


def solve_dense(
    x, h, kern: AbstractKernel, degree: int, smoothing, solver: str = "lu", background=None
):
    """The dense fit as a pure JAX function: returns (RBFModel, residual, finite). No checks.

    `x` (n, d) constraint points and `h` (n,) values in the user's units; `kern` with its radius
    in those units; `smoothing` lambda in those units; `background` None or a model whose values
    are subtracted from `h` (and added back by the model)."""
    from ._solve import solve_system

    if background is not None:
        h = h - background(x)
    shift, scale = unit_box(x)
    xn = (x - shift) / scale
    kn = kern.scaled(1.0 / scale)
    sm = jnp.asarray(smoothing, dtype=x.dtype) / scale**kern.homogeneity
    sol = solve_system(kn, xn, h, sm, degree, solver)
    finite = jnp.all(jnp.isfinite(sol.weights)) & jnp.all(jnp.isfinite(sol.coeffs))
    model = RBFModel(
        centres=xn,
        weights=sol.weights,
        coeffs=sol.coeffs,
        kernel=kn,
        shift=shift,
        scale=scale,
        residual=sol.residual,
        degree=degree,
        background=background,
    )
    return model, sol.residual, finite


def _checked(model, residual, finite, solver):
    from ._fit import RESIDUAL_TOL, check_solution

    r, f = concrete(residual), concrete(finite)
    if r is not None and f is not None:
        check_solution(float(r), bool(f), solver, 0, True)
        return model
    bad = ~finite | ~(residual <= RESIDUAL_TOL)
    msg = (
        f"jaxrbf.fit (traced): the {solver} solve is singular or does not reproduce its "
        f"constraints (relative residual above {RESIDUAL_TOL:.0e}); try smoothing > 0 or a "
        "smaller kernel radius"
    )
    return eqx.tree_at(lambda m: m.weights, model, eqx.error_if(model.weights, bad, msg))


def fit_traced(
    points, values, *, kernel, degree, smoothing, solver, radius, method, seed, background=None
):
    """`jaxrbf.fit` when an input is traced; same arguments (see the module docstring)."""
    from ._fit import AUTO_DENSE_LIMIT, METHODS, _check_size, check_background, checked_kernel

    x, h = _arrays(points, values)
    if method not in METHODS:
        raise InputError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    if degree not in (-1, 0, 1):
        raise InputError(f"`degree` must be -1 (no polynomial), 0 or 1, got {degree!r}")
    kern = checked_kernel(kernel, radius, degree, x.shape)
    n, dim = x.shape
    k = n_poly(degree, dim)
    if method == "global":
        raise InputError(
            "method='global' (greedy centre selection) is not differentiable: its choice of "
            "centres is a discrete host-side loop; use method='dense' or 'partition' under "
            "jax.grad / jax.jit"
        )
    if method == "auto":
        method = "dense" if (solver is not None or n + k <= AUTO_DENSE_LIMIT) else "partition"
    if background is not None:
        check_background(background, dim, method)
    if method == "partition":
        if solver is not None:
            raise InputError(
                "`solver` applies to method='dense' or 'global'; the partition method solves its "
                "small local systems directly (leave `solver` unset)"
            )
        return fit_partition_traced(x, h, kern, degree, smoothing, seed)
    solver = "lu" if solver is None else solver
    if solver not in ("lu", "cholesky"):
        raise InputError(
            f"solver={solver!r} is not available under jax.grad / jax.jit: its preconditioner is "
            "built on the host; use solver='lu' or 'cholesky' (both differentiate through "
            "lineax.linear_solve)"
        )
    _check_size(n + k, solver)
    model, residual, finite = solve_dense(x, h, kern, degree, smoothing, solver, background)
    return _checked(model, residual, finite, solver)


# --- partition of unity -----------------------------------------------------------------------


def fit_partition_traced(x, h, kern, degree, smoothing, seed: int = 0):
    """A `PartitionModel` whose weights are differentiable functions of `x`, `h`, the kernel
    radius and `smoothing`, with the layout built from the concrete points (module docstring)."""
    from ._fit import PARTITION_RESIDUAL_TOL
    from ._prepare import unit_box_transform

    if isinstance(x, jax.core.Tracer):
        raise InputError(
            "the partition-of-unity fit is differentiable with respect to the values, the kernel "
            "radius and the smoothing, but not the constraint points (nor so the offset d, which "
            "moves them): its patch layout (balls, memberships, blend weights) depends on the "
            "points through discrete host-side choices, so a gradient that held it fixed would "
            "be wrong; use method='dense' to differentiate with respect to points or offset"
        )
    xc = np.asarray(x)
    shift, scale = unit_box_transform(xc)
    model = _partition_level(x, xc, h, kern, degree, smoothing, shift, scale, seed, 0)
    err = jnp.max(jnp.abs(model(lax.stop_gradient(x)) - lax.stop_gradient(h)))
    rel = err / jnp.maximum(jnp.max(jnp.abs(lax.stop_gradient(h))), 1e-300)
    r = concrete(rel)
    if r is not None and not (np.isfinite(r) and r <= PARTITION_RESIDUAL_TOL):
        raise SolveError(
            f"the partition-of-unity fit does not reproduce its constraints: relative residual "
            f"{float(r):.2e} > {PARTITION_RESIDUAL_TOL:.0e}; try a smaller radius, smoothing > 0, "
            "or the cubic kernel"
        )
    return eqx.tree_at(lambda m: m.residual, model, rel)


def _partition_level(x, xc, h, kern, degree, smoothing, shift, scale, seed, level):
    from . import _partition as pu

    n = xc.shape[0]
    if n <= pu.BASE_SIZE:
        base_kernel = make_kernel("cubic" if xc.shape[1] == 3 else "thin-plate")
        model, residual, finite = solve_dense(x, h, base_kernel, 1, smoothing, "cholesky")
        return _checked(model, residual, finite, "cholesky")
    rng = np.random.default_rng(seed + level)
    sub = np.sort(rng.choice(n, max(pu.BASE_SIZE // 2, n // pu.COARSENING), replace=False))
    background = _partition_level(
        x[sub], xc[sub], h[sub], kern, degree, smoothing, shift, scale, seed, level + 1
    )
    dim = xc.shape[1]
    xn_c = (xc - shift) / scale
    xn = (x - shift) / scale
    patches = pu.make_patches(xn_c, leaf=pu.LEAF)
    kn = kern.scaled(1.0 / scale)
    sm = jnp.asarray(smoothing, dtype=float) / scale**kern.homogeneity
    xpad = jnp.concatenate([xn, jnp.zeros((1, dim))])
    hpad = jnp.concatenate([h, jnp.zeros(1)])
    mem = patches.members
    w, c, rel = pu._fit_batch(
        kn,
        xpad[mem],
        hpad[mem],
        jnp.asarray(patches.mask),
        jnp.asarray(patches.origin),
        jnp.asarray(patches.radius),
        degree,
        sm,
    )
    finite = concrete(jnp.all(jnp.isfinite(w)))
    if finite is not None and not bool(finite):
        raise SolveError("local fits produced NaN: their points are degenerate; try smoothing > 0")
    m = mem.shape[1]
    weights = jnp.concatenate([w, jnp.zeros((1, m))])
    coeffs = jnp.concatenate([c, jnp.zeros((1, c.shape[1]))])
    centres = jnp.concatenate([xpad[mem], jnp.zeros((1, m, dim))])
    glo, cs, dims, cell_row, table = pu.lookup_grid(patches.origin, patches.radius)
    return pu.PartitionModel(
        origin=jnp.asarray(np.concatenate([patches.origin, np.full((1, dim), 1e6)])),
        radius=jnp.asarray(np.concatenate([patches.radius, [1.0]])),
        centres=centres,
        weights=weights,
        coeffs=coeffs,
        cell_row=jnp.asarray(cell_row),
        table=jnp.asarray(table),
        grid_lo=jnp.asarray(glo),
        cell_size=jnp.asarray(cs),
        kernel=kn,
        background=background,
        shift=jnp.asarray(shift, dtype=float),
        scale=jnp.asarray(scale, dtype=float),
        residual=jnp.max(rel),
        degree=degree,
        grid_dims=dims,
    )
