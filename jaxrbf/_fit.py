"""`fit`: scattered-data interpolation with RBFs (paper eq. 3-8), the core every other path uses."""

from __future__ import annotations

import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._constraints import VOLUME_SMOOTHING, Constraints, log
from ._errors import InputError, SolveError
from ._model import AbstractModel, RBFModel, n_poly
from ._prepare import find_duplicates, unit_box_transform
from ._schwarz import decompose
from ._solve import SOLVERS, solve_system
from ._system import rounding_floor
from ._util import available_memory as _available_memory
from .io import as_points
from .kernels import AbstractKernel, make_kernel

#: Dense solves at or above this many unknowns crash OpenBLAS's multithreaded LU on the reference
#: machine (a segmentation fault, which cannot be caught; see DESIGN.md), so they are refused.
DENSE_LIMIT = 21_000
#: Stopping tolerances of the iterative solvers (see `fit`).
DEFAULT_RTOL = {"cg": 1e-11, "gmres": 1e-8}
#: A fit whose relative residual max|B x - rhs| / max|rhs| exceeds this is an error.
RESIDUAL_TOL = 1e-6
#: ... unless float64 rounding alone may leave more for weights this large
#: (`jaxrbf._system.rounding_floor`) and that is within FLOOR_TOL: then f itself cannot be
#: evaluated more exactly than that anywhere, and a residual within it is as exact as the
#: arithmetic allows (the beetle's 1,148 samples fitted for their slabs: 1.36e-6 with CG, 7.3e-7
#: with LU, floor 8.0e-6). Beyond FLOOR_TOL the weights are too large to trust at all (a Gaussian
#: of radius 1e4: residual 37, floor 1,169): an error as before.
FLOOR_TOL = 1e-4
METHODS = ("auto", "dense", "partition", "global")
#: `method="auto"` solves one global system up to this many unknowns (a few seconds with CG),
#: and blends local fits (partition of unity) beyond.
AUTO_DENSE_LIMIT = 15_000


def _check_size(n: int, solver: str) -> None:
    if solver not in ("lu", "cholesky"):
        return
    if n >= DENSE_LIMIT:
        raise InputError(
            f"{n:,} unknowns is too many for the dense {solver} solver (limit {DENSE_LIMIT:,}: larger "
            "dense LAPACK solves crash OpenBLAS); use solver='cg' or 'gmres' (iterative) or fewer "
            "points"
        )
    need = 3 * 8 * n * n
    avail = _available_memory()
    if avail is not None and need > avail:
        raise InputError(
            f"the dense {solver} solve of {n:,} unknowns needs about {need / 2**30:.1f} GiB but "
            f"{avail / 2**30:.1f} GiB is available; use solver='cg' or 'gmres' or fewer points"
        )


def unpack(points, values):
    """`(points, values)` from a `Constraints` or from the two arrays, unchecked."""
    if isinstance(points, Constraints):
        if values is not None:
            raise InputError("give either `Constraints` or `points` and `values`, not both")
        return points.points, points.values
    if values is None:
        raise InputError("`values` is missing: give the value f must take at each point")
    return points, values


def points_and_values(points, values) -> tuple[np.ndarray, np.ndarray]:
    """Validated (n, d) points and (n,) finite values, from arrays or from a `Constraints`."""
    points, values = unpack(points, values)
    x = as_points(points, "points", dims=tuple(range(1, 33)))
    h = np.asarray(values, dtype=float)
    if h.ndim != 1 or len(h) != len(x):
        raise InputError(f"`values` must have shape ({len(x)},) to match `points`, got {h.shape}")
    if not np.all(np.isfinite(h)):
        raise InputError(f"`values` has {int(np.sum(~np.isfinite(h)))} NaN or infinite entries")
    return x, h


def choose_method(method: str, unknowns: int, verbose: bool = False) -> str:
    """`method`, with `auto` resolved: `dense` up to `AUTO_DENSE_LIMIT` unknowns, else
    `partition`. The choice is reported on stderr when `verbose`, or when it is not `dense`."""
    if method not in METHODS:
        raise InputError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    if method != "auto":
        return method
    method = "dense" if unknowns <= AUTO_DENSE_LIMIT else "partition"
    if verbose or method != "dense":
        log(f"method auto: {method} ({unknowns:,} unknowns; dense up to {AUTO_DENSE_LIMIT:,})")
    return method


def _store_matrix(n: int) -> bool:
    """Whether CG may keep the n x n null-space matrix (else it applies it block by block)."""
    avail = _available_memory()
    return n < DENSE_LIMIT and (avail is None or 2 * 8 * n * n < avail)


def fit(
    points,
    values=None,
    *,
    kernel: str | AbstractKernel = "cubic",
    degree: int = 1,
    smoothing: float = 0.0,
    solver: str | None = None,
    radius: float | None = None,
    rtol: float | None = None,
    max_steps: int | None = None,
    method: str = "auto",
    tol: float | None = None,
    seed: int = 0,
    background: AbstractModel | None = None,
    verbose: bool = False,
) -> AbstractModel:
    """Fit f(x) = sum_j w_j phi(|x - c_j|) + p(x) through `values` at `points` (eq. 5-6).

    Like `scipy.interpolate.RBFInterpolator(points, values, kernel=..., degree=..., smoothing=...,
    epsilon=1/radius)`, with the centres at the points. Inputs are shifted and scaled into the unit
    box before the solve (one uniform scale), and the model keeps that transform, so it is evaluated
    in the input's own coordinates.

    **Arguments:**
    - `points`: (n, d) array, or a `Constraints` (then `values` must be None).
    - `values`: (n,) values at the points.
    - `kernel`: a name from `jaxrbf.kernels.KERNELS` (`cubic`, `linear`, `thin-plate`, `gaussian`,
      `multiquadric`, `inverse-multiquadric`, `wendland`) or a kernel instance.
    - `degree`: polynomial degree: 1 (the paper's eq. 6), 0 or -1 (none); at least the kernel's
      `min_degree`.
    - `smoothing`: lambda >= 0 added to the diagonal (A + lambda I); 0 interpolates.
    - `method`: `dense` (one global system, solved by `solver`), `partition` (a
      partition-of-unity blend of small local fits, `jaxrbf._partition`: for large inputs, memory
      O(n)), `global` (exact global interpolation at large n: greedy centre selection with
      matrix-free `solver`, `jaxrbf._greedy`), or `auto` (the default): `dense` up to
      `AUTO_DENSE_LIMIT` unknowns, `partition` beyond (and `dense` whenever `solver` is given);
      it says what it picked on stderr.
    - `solver`: for `dense` and `global`; `lu` (the paper's; the default for `dense`), `cholesky` (null-space form), `cg` (conjugate gradients on
      the null-space form, preconditioned by overlapping local solves and a coarse solve: the
      fastest for a few thousand points and more), `gmres` (matrix-free: the kernel matrix is
      applied block by block and never stored; same preconditioner).
    - `radius`: the kernel's length scale in the points' units (Gaussian, multiquadrics, Wendland's
      radius of support); not used by the others.
    - `rtol`, `max_steps`: tolerance and iteration cap of CG and GMRES (default min(20 n, 5000)
      iterations). Both stop when max|residual| <= rtol max|values|: CG on its recursive residual
      (default rtol 1e-11), GMRES on the true one, which rounding keeps near 1e-9 for large
      polyharmonic systems (default rtol 1e-8).
    - `tol`, `seed`: `global` only: the absolute residual to reach at every constraint (default
      1e-3 max|values|) and the seed of its initial subset.
    - `background`: None, or a model g (e.g. `jaxrbf.surface_background(points, normals)`): the
      RBF part is fitted to `values` - g(`points`) and the returned model is f = RBF part + g
      (the dense method only). Surface fits with kernels that decay far from their centres
      (Gaussian, inverse multiquadric, Wendland) want one, or their bare polynomial makes
      spurious surface away from the data (see `jaxrbf._background`).
    - `verbose`: report the solve and its residual on stderr.

    **Returns:** an `RBFModel` (`dense`, `global`) or a `PartitionModel` (`partition`). Its
    `residual` is the relative residual max|f(x_i) - h_i| / max|h| (for `partition`, measured at
    up to 50,000 of the constraints).

    **Raises:** `InputError` for unusable input (with what was expected), `SolveError` when the
    system is singular or the solution does not reproduce the constraints.

    Differentiable: when any of `points`, `values`, `radius`, `smoothing` (or a kernel's radius)
    is a JAX tracer (`jax.grad`, `jax.jvp`, `jax.jit`, an optimistix solve), `fit` takes a traced
    path (`jaxrbf._difffit`): the dense method with `lu` or `cholesky` (differentiated by
    `lineax.linear_solve`, no hand-written adjoint), or `partition` (differentiable in the values,
    radius and smoothing; its points must be concrete). The host-only checks (NaN, duplicates,
    coplanar points) are skipped there; the residual check runs where the values are concrete
    and is compiled in (`equinox.error_if`) under `jit`.

    Precision: float64 throughout (see `jaxrbf._solve`).
    """
    if not jax.config.jax_enable_x64:
        raise InputError(
            "fit needs JAX's 64-bit mode, which was turned off after importing jaxrbf; "
            "call jax.config.update('jax_enable_x64', True)"
        )
    if is_traced(points, values, kernel, radius, smoothing):
        from ._difffit import fit_traced

        return fit_traced(
            points,
            values,
            kernel=kernel,
            degree=degree,
            smoothing=smoothing,
            solver=solver,
            radius=radius,
            method=method,
            seed=seed,
            background=background,
        )
    n_volume = points.n_volume if isinstance(points, Constraints) else 0
    x, h = points_and_values(points, values)
    if method not in METHODS:
        raise InputError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    if solver is not None and solver not in SOLVERS:
        raise InputError(f"unknown solver {solver!r}; expected one of {', '.join(SOLVERS)}")
    if solver is not None and method == "partition":
        raise InputError(
            "`solver` applies to method='dense' or 'global'; the partition method solves its "
            "small local systems directly (leave `solver` unset)"
        )
    if degree not in (-1, 0, 1):
        raise InputError(f"`degree` must be -1 (no polynomial), 0 or 1, got {degree!r}")
    smoothing = float(smoothing)
    if not (np.isfinite(smoothing) and smoothing >= 0):
        raise InputError(f"`smoothing` must be a number >= 0, got {smoothing!r}")
    kern = checked_kernel(kernel, radius, degree, x.shape)
    n, dim = x.shape
    k = n_poly(degree, dim)
    if not np.any(h != 0):
        raise InputError(
            "every value is 0, so the only solution is f = 0 (the paper's trivial solution); "
            "add off-surface points, e.g. with Constraints.from_points(points, normals)"
        )
    shift, scale = unit_box_transform(x)
    xn = (x - shift) / scale
    if smoothing == 0:
        dup = find_duplicates(xn, 1e-9)
        if dup.any():
            j = int(np.argmax(dup))
            raise InputError(
                f"`points` has {int(dup.sum())} duplicate points (first: row {j}); an interpolant cannot "
                "take two values at one point: merge them or set smoothing > 0"
            )
    if degree == 1:
        s = np.linalg.svd(xn - xn.mean(axis=0), compute_uv=False)
        if s[-1] <= 1e-9 * s[0]:
            raise InputError(
                f"all {n} points lie on one {'plane' if dim == 3 else 'hyperplane'}, so the degree-1 "
                "polynomial is not determined; use degree=0 or add points off that plane"
            )
    if method == "auto" and (solver is not None or background is not None):
        method = "dense"  # a solver or a background was asked for: one global system
    method = choose_method(method, n + k, verbose)
    if background is not None:
        h = h - background_values(background, x, method)
    if method == "global":
        from ._greedy import greedy_fit

        model, report = greedy_fit(
            x,
            h,
            kernel=kern,
            degree=degree,
            smoothing=smoothing,
            tol=tol,
            solver=solver or "cg",
            seed=seed,
            verbose=verbose,
        )
        if not report.converged:
            raise SolveError(
                f"the global fit did not reach tol at every constraint: {report.summary()}"
            )
        return model
    if method == "partition":
        return _fit_partition(x, h, kern, degree, smoothing, shift, scale, seed, verbose, n_volume)
    if solver is None:
        solver = "lu"
    _check_size(n + k, solver)
    kern = kern.scaled(1.0 / scale)
    # The solve runs in the unit box; scale the smoothing so that it means what it means in the
    # input's units (as in scipy's RBFInterpolator): A_unit = A_input / scale^homogeneity.
    smoothing = smoothing / scale**kern.homogeneity
    if smoothing and n_volume:  # row by row: the volume constraints are held
        smoothing = np.where(np.arange(n) >= n - n_volume, VOLUME_SMOOTHING, 1.0) * smoothing
    t0 = time.perf_counter()
    if verbose:
        log(f"solving {n + k:,} unknowns: {kern.name} kernel, degree {degree}, {solver}, float64")
    decomposition = None
    if solver in ("cg", "gmres"):
        decomposition = tuple(jnp.asarray(a) for a in decompose(xn))
    sol = solve_system(
        kern,
        jnp.asarray(xn),
        jnp.asarray(h),
        jnp.asarray(smoothing),
        degree,
        solver,
        DEFAULT_RTOL.get(solver, 1e-11) if rtol is None else rtol,
        max_steps,
        decomposition,
        solver == "cg" and _store_matrix(n + k),
    )
    residual = float(sol.residual)
    steps = int(sol.steps)
    finite = bool(jnp.all(jnp.isfinite(sol.weights)) & jnp.all(jnp.isfinite(sol.coeffs)))
    if verbose:
        extra = {
            "gmres": f", {steps} GMRES restart cycles of <= 100 iterations",
            "cg": f", {steps} CG iterations",
        }.get(solver, "")
        log(f"solved in {time.perf_counter() - t0:.2f} s; relative residual {residual:.2e}{extra}")
    floor = 0.0
    if finite and residual > RESIDUAL_TOL:
        # large weights (an ill-conditioned system) put the rounding of B x itself above the
        # fixed tolerance: a residual within it is as exact as float64 allows, not a failed solve
        floor = float(
            rounding_floor(
                kern,
                jnp.asarray(xn),
                degree,
                jnp.asarray(smoothing),
                sol.weights,
                sol.coeffs,
                jnp.asarray(h),
            )
        )
        if verbose and residual <= allowed_residual(floor):
            log(
                f"relative residual {residual:.2e} is within what float64 rounding leaves for "
                f"weights this large ({floor:.1e}): accepted"
            )
    check_solution(residual, finite, solver, steps, bool(sol.ok), floor)
    return RBFModel(
        centres=jnp.asarray(xn),
        weights=sol.weights,
        coeffs=sol.coeffs,
        kernel=kern,
        shift=jnp.asarray(shift),
        scale=jnp.asarray(scale),
        residual=jnp.asarray(residual),
        degree=degree,
        background=background,
    )


def check_background(background, dim: int, method: str) -> None:
    """That `background` (not None) can be the background of a `fit` of `dim`-D points by
    `method` (both the concrete and the traced path)."""
    if not isinstance(background, AbstractModel):
        raise InputError(
            f"`background` must be a jaxrbf model (e.g. jaxrbf.surface_background(points, "
            f"normals)) or None, got {type(background).__name__}"
        )
    if background.dim != dim:
        raise InputError(f"`background` is a {background.dim}-D model but the points are {dim}-D")
    if method != "dense":
        raise InputError(
            f"`background` applies to method='dense'; method={method!r} has its own coarse "
            "levels far from the data"
        )


def background_values(background, x, method: str):
    """g(`x`) of a `background` model for `fit`, after `check_background`."""
    check_background(background, x.shape[1], method)
    g = background(x)
    if not bool(jnp.all(jnp.isfinite(g))):
        raise InputError("`background` is not finite at every point")
    return np.asarray(g)


def checked_kernel(kernel, radius, degree: int, shape: tuple[int, int]):
    """The kernel, after checking that `degree` makes its system well posed and that `shape`
    (n points, d dimensions) holds more points than the polynomial has terms."""
    kern = make_kernel(kernel, radius)
    if degree < kern.min_degree:
        raise InputError(
            f"the {kern.name} kernel needs a polynomial of degree >= {kern.min_degree} for a "
            f"well-posed system, got degree={degree}"
        )
    n, dim = shape
    k = n_poly(degree, dim)
    if n <= k:
        raise InputError(
            f"{n} points cannot determine a degree-{degree} polynomial in {dim}-D plus weights; "
            f"give more than {k}"
        )
    return kern


def is_traced(*trees) -> bool:
    """Whether any array leaf of `trees` is a JAX tracer (under `jit`, `grad`, `vmap`): then `fit`
    takes its traced, differentiable path (`jaxrbf._difffit`)."""
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(trees))


def allowed_residual(floor: float) -> float:
    """The relative residual a dense fit may leave, given its rounding floor."""
    return max(RESIDUAL_TOL, min(floor, FLOOR_TOL))


def check_solution(
    residual: float, finite: bool, solver: str, steps: int, ok: bool, floor: float = 0.0
) -> None:
    """Raise `SolveError` when a dense solve produced NaN, or does not reproduce its constraints
    (relative residual above `RESIDUAL_TOL`, or above `floor`, the residual that rounding alone
    may leave, `jaxrbf._system.rounding_floor`, where that is larger but within `FLOOR_TOL`)."""
    if not finite or not np.isfinite(residual):
        raise SolveError(
            f"the {solver} solve produced NaN or infinite weights: the system is singular "
            "(duplicate or degenerate points, or a kernel radius far too large); "
            "try smoothing > 0 or another kernel"
        )
    if residual > allowed_residual(floor):
        unit = "restart cycles" if solver == "gmres" else "iterations"
        why = (
            f"{solver} stopped after {steps} {unit} without converging"
            if solver in ("cg", "gmres") and not ok
            else "the system is nearly singular"
        )
        raise SolveError(
            f"the fit does not reproduce its constraints: relative residual {residual:.2e} > "
            f"{RESIDUAL_TOL:.0e} ({why}); try solver='lu', smoothing > 0, or fewer/cleaner points"
        )


#: A partition-of-unity fit interpolates every constraint its patches hold (to ~1e-11); a patch
#: that had to be capped (`jaxrbf._partition.MAX_POINTS`) approximates a few. Beyond this the
#: fit is an error. Measured: a scan of the fandisk (20,000 points, outliers removed) has one
#: constraint of 60,000 at 6.7e-3 (every other at 1e-14), harmless; badly conditioned local
#: systems give 0.1 and more.
PARTITION_RESIDUAL_TOL = 1e-2
#: Constraints sampled for the residual of a partition-of-unity fit.
RESIDUAL_SAMPLE = 50_000


def _partition_residuals(model, x, h):
    """(residual at the constraints, residual at those the finest level's patches cover, count
    of the others) of a partition fit, relative to max |h|, over a sample of the constraints.

    Where the patches' weights sum to at least `TAU`, f is their blend alone, and each patch
    interpolates (with smoothing: approximates, by its own system) every constraint its ball
    holds, so a residual there is a failed local solve. Where they sum to less, f hands over to
    the coarser levels, which are fitted to a subsample and need not hold the constraint: a
    residual there is the layout's (a patch cut to `MAX_POINTS` leaves its own points near its
    rim), not the solves'; the count is reported."""
    from ._partition import TAU, PartitionModel

    if len(x) > RESIDUAL_SAMPLE:
        idx = np.random.default_rng(0).choice(len(x), RESIDUAL_SAMPLE, replace=False)
        x, h = x[idx], h[idx]
    err = np.abs(np.asarray(model(jnp.asarray(x))) - h) / max(float(np.abs(h).max()), 1e-300)
    if isinstance(model, PartitionModel):
        covered = model.coverage(x) >= TAU
    else:
        covered = np.ones(len(x), dtype=bool)
    held = float(err[covered].max()) if covered.any() else 0.0
    return float(err.max()), held, int((~covered).sum())


def _fit_partition(x, h, kern, degree, smoothing, shift, scale, seed, verbose, n_volume=0):
    from ._partition import PartitionModel, check_memory, fit_partition

    check_memory(len(x), x.shape[1])
    t0 = time.perf_counter()
    if verbose:
        log(f"fitting {len(x):,} constraints by partition of unity: {kern.name} kernel, float64")
    model = fit_partition(
        x,
        h,
        kernel=kern,
        degree=degree,
        smoothing=smoothing,
        shift=shift,
        scale=scale,
        seed=seed,
        verbose=verbose,
        n_volume=n_volume,
    )
    # The finest level's worst residual of a local solve against its own system (A + lambda I
    # included), as `fit_partition` leaves it in the model.
    local = float(model.residual)
    # Volume constraints are each fitted by the levels that reach them, and the blend of a
    # finer level that does not hold one moves f there a little: only the surface's count.
    keep = len(x) - n_volume
    residual, held, isolated = _partition_residuals(model, x[:keep], h[:keep])
    if verbose:
        layout = (
            f"{model.n_patches:,} patches on {model.n_levels} levels"
            if isinstance(model, PartitionModel)
            else "few enough constraints for its one global fit"
        )
        extra = (
            f" ({held:.2e} at those the patches cover; {isolated:,} of the sample near the rims "
            "of every patch that holds them, where the coarser levels blend in)"
            if isolated
            else ""
        )
        log(
            f"partition of unity: {layout} in {time.perf_counter() - t0:.1f} s; relative "
            f"residual {residual:.2e} at the constraints{extra}"
        )
    if not (np.isfinite(residual) and np.isfinite(local)):
        raise SolveError(
            "the partition-of-unity fit produced NaN or infinite values at its constraints: its "
            "local systems are singular; try smoothing > 0, a smaller radius or the cubic kernel"
        )
    # The check is for failed solves, not for data an interpolant cannot follow: with
    # smoothing > 0 the fit approximates on purpose, and the residual at the constraints is the
    # smoothing's doing (reported above); each local solve must still satisfy its own system.
    # Interpolating, the patches must reproduce the constraints they cover.
    bad = local if smoothing else max(local, held)
    if bad > PARTITION_RESIDUAL_TOL:
        raise SolveError(
            f"the partition-of-unity fit does not reproduce its constraints: relative residual "
            f"{bad:.2e} > {PARTITION_RESIDUAL_TOL:.0e} where its local fits hold them: its local "
            "systems are too badly conditioned (a kernel radius much larger than the point "
            "spacing does that); try a smaller radius, smoothing > 0, or the cubic kernel"
        )
    return eqx.tree_at(lambda m: m.residual, model, jnp.asarray(residual))
