"""`tune`: choose the offset d, the kernel radius (and the smoothing) by optimisation.

The paper leaves the choice of the basis function's radius to future work; here it is a
minimisation of an objective from `jaxrbf.objectives` (by default the held-out error) over the
logarithms of the parameters (so they stay positive, and steps are relative), with an optimistix
minimiser (BFGS by default) or least-squares solver (Levenberg-Marquardt, Gauss-Newton).

The optimiser is stepped from Python (optimistix's `init` / `step` / `terminate`), so that
progress can be shown and the path recorded; the result is the best point it evaluated, never
worse than the start (and, on the held-out objective, kept only where it beats the start by more
than one standard error of the held-out samples' paired errors). Quasi-Newton minimisers (BFGS)
ask for the objective only at one point per step (`state.y_eval`): `tune` evaluates it there
itself, value and gradient, and hands both to a
step compiled once per solver. For the held-out objective that evaluation is
`objectives.held_out_value_and_grad`: one LU factorisation serves the fit and the adjoint solve,
the kernel matrix's derivative is one fused pass per parameter, and its compiled pieces are
cached across calls (the LU solve even across kernels on the same samples). Other objectives are
differentiated in forward mode through `jaxrbf.fit` (`lineax.linear_solve`); other solvers step
the objective themselves.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._background import surface_background, wants_background
from ._constraints import DEFAULT_OFFSET, checked_samples, log, progress_bar
from ._errors import InputError
from .kernels import AbstractKernel, kernel_class

PARAMS = ("offset", "radius", "smoothing")
#: Default kernel radius, in median point spacings, per kernel (measured: see the README). The
#: Gaussian's, over its background (2,000 samples, Chamfer-L1 at 1.5 / 1.75 / 2 spacings): spot
#: 0.182 / 0.180 / 0.181%, the bunny 0.272 / 0.270 / 0.276%, fandisk 0.262 / 0.276 / 0.319%.
DEFAULT_RADIUS_SPACINGS = {
    "gaussian": 1.75,
    "multiquadric": 2.0,
    "inverse-multiquadric": 2.0,
    "wendland": 32.0,
}
#: Multiples of the starting offset that `tune` evaluates before its optimiser starts, for fits
#: over a background (see `tune`).
OFFSET_SCAN = (2.0, 4.0)
#: Tuning searches each parameter within this factor of its starting value.
SEARCH_FACTOR = 30.0


def default_offset(points) -> float:
    """The default offset d in the points' units: `DEFAULT_OFFSET` (1%) of the bounding-box
    diagonal."""
    from ._prepare import diagonal

    return DEFAULT_OFFSET * diagonal(np.asarray(points, dtype=float))


def default_radius(kernel, points) -> float | None:
    """The default kernel radius in the points' units: `DEFAULT_RADIUS_SPACINGS[kernel]` median
    nearest-neighbour spacings of the surface samples; None for kernels without a radius."""
    from .objectives import point_spacing

    cls = type(kernel) if isinstance(kernel, AbstractKernel) else kernel_class(kernel)
    if not cls.has_radius:
        return None
    return DEFAULT_RADIUS_SPACINGS[cls.name] * point_spacing(points)


@dataclasses.dataclass
class TuneReport:
    """What `tune` did.

    **Fields:** `params` (names tuned), `initial` / `final` (parameter values, points' units),
    `initial_objective` / `final_objective`, `iterations` (optimiser steps), `path` (the offsets
    scanned first, if any, then one dict per step: the accepted parameters and objective),
    `converged` (the optimiser's own test passed), `improved` (the result is better than the start; if not, the start is returned), `message`,
    `seconds`, `solver` (the optimiser's class name), `objective` (its name), `background`
    (whether the fits were over `jaxrbf.surface_background`), `standard_error` (of the
    improvement over the start, from the held-out samples' paired errors; NaN where not
    measured: other objectives, or no improvement)."""

    params: tuple[str, ...]
    initial: dict[str, float]
    final: dict[str, float]
    initial_objective: float
    final_objective: float
    iterations: int
    path: list[dict[str, float]]
    converged: bool
    improved: bool
    message: str
    seconds: float
    solver: str
    objective: str
    background: bool = False
    standard_error: float = float("nan")

    def summary(self) -> str:
        def fmt(d):
            return ", ".join(f"{k} {v:.4g}" for k, v in d.items())

        lines = [
            f"tune ({self.solver}, {self.objective} objective"
            f"{', over a background' if self.background else ''}): {self.iterations} steps in "
            f"{self.seconds:.1f} s; {self.message}",
            f"  initial: {fmt(self.initial)}; objective {self.initial_objective:.5g}",
            f"  final:   {fmt(self.final)}; objective {self.final_objective:.5g}",
        ]
        return "\n".join(lines)


def _standard_error(evaluated, f0: float, best: float) -> float:
    """The standard error of the mean of the paired differences between the held-out samples'
    errors at the start (objective `f0`) and at the best point (`best`), from the evaluations
    recorded by `tune` as (objective, per-sample errors); NaN when either is missing."""

    def errors(f):
        for fe, per in evaluated:
            if np.isclose(fe, f, rtol=1e-9, atol=0.0):
                return per
        return None

    a, b = errors(f0), errors(best)
    if a is None or b is None or a.shape != b.shape or len(a) < 2:
        return float("nan")
    d = a - b
    if not np.all(np.isfinite(d)):
        return float("nan")
    return float(np.std(d, ddof=1) / np.sqrt(len(d)))


def _not_finite_at_start(obj_name: str, start: dict) -> InputError:
    return InputError(
        f"the {obj_name} objective is not finite at the starting point {start}: "
        "the fit fails there; give another starting offset/radius"
    )


def _objective_fn(objective) -> tuple[Callable, str]:
    from . import objectives as obj

    names = {
        "held-out": obj.held_out_error,
        "kfold": obj.kfold_error,
        "loocv": obj.loocv_error,
    }
    if callable(objective):
        return objective, getattr(objective, "__name__", "custom")
    if objective not in names:
        raise InputError(
            f"unknown objective {objective!r}; expected one of {', '.join(names)} or a function"
        )
    return names[objective], objective


def _check_params(params, kernel, start: dict) -> tuple[str, ...]:
    if isinstance(params, str):
        params = (params,)
    params = tuple(params)
    if not params:
        raise InputError("`params` is empty: name at least one of offset, radius, smoothing")
    for p in params:
        if p not in PARAMS:
            raise InputError(
                f"unknown parameter {p!r} to tune; expected some of {', '.join(PARAMS)}"
            )
    if len(set(params)) != len(params):
        raise InputError(f"`params` names a parameter twice: {params}")
    cls = type(kernel) if isinstance(kernel, AbstractKernel) else kernel_class(kernel)
    if "radius" in params and not cls.has_radius:
        raise InputError(
            f"the {cls.name} kernel has no radius to tune; use params=('offset',) or a kernel "
            "with a radius (gaussian, multiquadric, inverse-multiquadric, wendland)"
        )
    for name, value in start.items():
        if value is None:
            continue
        positive = name != "smoothing" or name in params
        if not np.isfinite(value) or value < 0 or (positive and value == 0):
            hint = (
                "; tuning works in log space, so start the smoothing at a small positive value"
                if name == "smoothing" and name in params
                else ""
            )
            raise InputError(
                f"`{name}` must be a {'positive' if positive else 'non-negative'} number, "
                f"got {value!r}{hint}"
            )
    return params


def _rescaled(state, y, scale):
    """A quasi-Newton state after its first step (which evaluated f and its gradient at `y`
    with the objective unscaled) as if the objective had been divided by `scale` from the start:
    f and the gradient divided by it, and so the first descent direction and the next point to
    evaluate. The alternative, restarting the solver, evaluates the start a second time (one fit
    and its tangents). None where the state is not the expected optimistix quasi-Newton state
    (then the caller restarts)."""
    try:
        info = state.f_info
        if not hasattr(info, "hessian_inv"):
            return None
        state = eqx.tree_at(
            lambda st: (st.f_info.f, st.f_info.grad, st.descent_state.newton, st.y_eval),
            state,
            (
                info.f / scale,
                jax.tree.map(lambda v: v / scale, info.grad),
                jax.tree.map(lambda v: v / scale, state.descent_state.newton),
                jax.tree.map(lambda a, b: a + (b - a) / scale, y, state.y_eval),
            ),
        )
    except (AttributeError, TypeError, ValueError):
        return None
    return state


#: Options of the quasi-Newton steps (`_given` is linear in y: either mode is exact and cheap).
_QN_OPTIONS = {"autodiff_mode": "fwd"}


def _given(y, args):
    """The objective as a quasi-Newton step sees it: its value and gradient at the point the step
    evaluates (`state.y_eval`, computed outside the step and passed in `args` with the scale),
    as a function of y with that value and derivative there."""
    scale, f, g = args
    lin = sum(jnp.sum(g[k] * (y[k] - jax.lax.stop_gradient(y[k]))) for k in y)
    return (f + lin) / scale, None


# Compiled once per solver and parameter names (not per call, kernel or data): the objective is
# evaluated outside them.
@eqx.filter_jit
def _qn_init(solver, y, args):
    f_struct = jax.ShapeDtypeStruct((), jnp.float64)
    return solver.init(_given, y, args, _QN_OPTIONS, f_struct, None, frozenset())


@eqx.filter_jit
def _qn_step(solver, y, state, args):
    return solver.step(_given, y, args, _QN_OPTIONS, state, frozenset())


@eqx.filter_jit
def _qn_terminate(solver, y, state, args):
    return solver.terminate(_given, y, args, _QN_OPTIONS, state, frozenset())


def _evaluator(fn_obj, call, p, nrm, kernel, degree, fit_solver, fixed, lo, hi, background):
    """y -> (objective, gradient dict, per-sample errors or None) for the quasi-Newton loop of
    `tune`, on the host. The held-out objective with LU fits: `objectives.held_out_value_and_grad`
    (its host-side data prepared once; with the error of each held-out sample); any other:
    forward mode through it, compiled for this call (no per-sample errors)."""
    from . import objectives as obj

    if fn_obj is obj.held_out_error and fit_solver == "lu":
        data = obj.held_out_data(p, nrm, background=background)
        base = {
            k: jnp.asarray(1.0 if fixed.get(k) is None else fixed[k], dtype=float) for k in PARAMS
        }
        bounds = [{k: jnp.asarray(v, dtype=float) for k, v in b.items()} for b in (lo, hi)]

        def evaluate(y, gradient=True):
            f, g, _, per = obj.held_out_value_and_grad(
                y,
                *bounds,
                base,
                data,
                kernel=kernel,
                degree=degree,
                gradient=gradient,
                pointwise=True,
            )
            return f, g, per

        return evaluate

    def value(y):
        f = call(y, False)
        return jnp.where(jnp.isnan(f), jnp.inf, f)

    def value_and_grad(y):
        f, lin = jax.linearize(value, y)
        return f, jax.jacfwd(lin)(y)

    vg = jax.jit(value_and_grad)

    def evaluate(y, gradient=True):
        f, g = vg(y)
        return f, {k: jnp.where(jnp.isfinite(f), v, 0.0) for k, v in g.items()}, None

    return evaluate


def support_floor(points, padding: float = 0.05, samples: int = 12) -> float:
    """The smallest radius for which every point of the points' bounding box, grown by
    `padding` of its size as `polygonize` does, has a sample within it (sampled on a
    `samples`^d lattice over the box; a KD-tree query, on the host)."""
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=float)
    lo, hi = p.min(axis=0), p.max(axis=0)
    pad = padding * (hi - lo)
    axes = [np.linspace(a, b, samples) for a, b in zip(lo - pad, hi + pad, strict=True)]
    box = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, p.shape[1])
    dist, _ = cKDTree(p).query(box, workers=-1)
    return float(dist.max())


def tune(
    points,
    normals,
    *,
    kernel: str | AbstractKernel = "cubic",
    params=None,
    objective="held-out",
    solver=None,
    offset: float | None = None,
    radius: float | None = None,
    smoothing: float = 0.0,
    degree: int = 1,
    max_steps: int = 4,
    fit_solver: str = "lu",
    background="auto",
    verbose: bool = False,
):
    """Tune `params` of a surface fit by minimising `objective`, then fit all the samples.

    **Arguments:**
    - `points`, `normals`: (n, d) surface samples and outward normals.
    - `kernel`: a kernel name (`jaxrbf.kernels.KERNELS`).
    - `params`: names among `offset`, `radius` (kernels with one), `smoothing` (start it > 0);
      default: `offset`, and `radius` for kernels with one.
    - `objective`: `"held-out"` (default), `"kfold"`, `"loocv"` (see `jaxrbf.objectives`) or a
      function with their signature.
    - `solver`: an optimistix minimiser (default `optimistix.BFGS(rtol=1e-3, atol=1e-3)`) or
      least-squares solver (e.g. `optimistix.LevenbergMarquardt(rtol=1e-3, atol=1e-3)`; then the
      objective is called with `residuals=True`).
    - `offset`, `radius`, `smoothing`: starting values (and the values of the parameters not
      tuned), in the points' units; default `default_offset` and `default_radius`.
    - `degree`: polynomial degree. `max_steps`: optimiser steps (each one fit and its gradient);
      over a background with the offset tuned, the first is instead a scan of the start's offset
      times 1, 2 and 4 (`OFFSET_SCAN`; three fits, values only), from whose best the optimiser
      starts (the held-out objective of a decaying kernel over a background is flat in the offset
      near the default: on fandisk the best offset was 4x the default, which BFGS did not reach).
    - `fit_solver`: the dense solver of every fit (`lu`, the default: measured faster than
      `cholesky` here once the null-space matrix is formed, or `cholesky`).
    - `background`: fit over `jaxrbf.surface_background` (of each fit's own samples): "auto" (the
      default) for the kernels that decay (Gaussian, inverse multiquadric), True or False. The
      objective is then called with `background=True`.
    - `verbose`: progress bar and report on stderr.

    **Returns:** `(model, report)`: the `RBFModel` fitted to all the samples with the tuned
    parameters, and a `TuneReport`. The parameters returned are the best the optimiser evaluated:
    if it failed or found nothing better, the report says so and they are the starting ones.
    With the held-out objective the start is also kept unless the best point beats it by more
    than one standard error (of the paired per-sample differences; the one-standard-error rule):
    measured on spot with the Gaussian kernel, an 8% lower objective came with a Chamfer distance
    no better than the start's.

    Each parameter is optimised as log(value), clipped to within `SEARCH_FACTOR` of its start.
    Precision: float64 (the fits); the optimiser's own arithmetic is float64 too.
    """
    import optimistix as optx

    from ._fit import fit
    from .objectives import capped_constraints

    t0 = time.perf_counter()
    p, nrm = checked_samples(points, normals)
    cls = type(kernel) if isinstance(kernel, AbstractKernel) else kernel_class(kernel)
    kname = cls.name
    if radius is not None and not cls.has_radius:
        raise InputError(f"the {kname} kernel has no radius; leave `radius` unset")
    start = {
        "offset": default_offset(p) if offset is None else float(offset),
        "radius": (default_radius(kname, p) if radius is None else float(radius))
        if cls.has_radius
        else None,
        "smoothing": float(smoothing),
    }
    if params is None:
        params = ("offset", "radius") if cls.has_radius else ("offset",)
    params = _check_params(params, kname, start)
    if int(max_steps) < 1:
        raise InputError(f"`max_steps` must be at least 1, got {max_steps!r}")
    fn_obj, obj_name = _objective_fn(objective)
    use_bg = wants_background(background, kname)
    if solver is None:
        solver = optx.BFGS(rtol=1e-3, atol=1e-3)
    least_squares = isinstance(solver, optx.AbstractLeastSquaresSolver)
    if not least_squares and not isinstance(solver, optx.AbstractMinimiser):
        raise InputError(
            f"`solver` must be an optimistix minimiser or least-squares solver, got {type(solver).__name__}"
        )
    fixed = {k: v for k, v in start.items() if k not in params}
    if "radius" in params and kname == "wendland":
        # A compactly supported fit is its bare polynomial wherever no centre lies within the
        # radius, and that polynomial crosses zero somewhere: spurious sheets that the held-out
        # error (measured on the surface) cannot see. Keep the support over the whole box.
        floor = float(np.log(support_floor(p)))
        start["radius"] = max(start["radius"], float(np.exp(floor)))
    y0 = {k: jnp.log(jnp.asarray(start[k], dtype=float)) for k in params}
    lo = {k: v - np.log(SEARCH_FACTOR) for k, v in y0.items()}
    hi = {k: v + np.log(SEARCH_FACTOR) for k, v in y0.items()}
    if "radius" in params and kname == "wendland":
        lo["radius"] = max(lo["radius"], floor)
        hi["radius"] = max(hi["radius"], floor)

    def values(y):
        return {k: jnp.exp(jnp.clip(y[k], lo[k], hi[k])) for k in params}

    def call(y, residuals):
        kw = dict(fixed, **values(y))
        return fn_obj(
            p,
            nrm,
            kernel=kname,
            offset=kw["offset"],
            radius=kw["radius"],
            smoothing=kw["smoothing"],
            degree=degree,
            solver=fit_solver,
            **({"residuals": True} if residuals else {}),
            **({"background": True} if use_bg else {}),
        )

    # The objective is divided by a scale (an array: changing it does not recompile).
    # Minimisers: BFGS starts from the identity Hessian, so its first move is the gradient itself;
    # after the first step (which only evaluates the start) the objective is rescaled so that
    # this move changes the largest parameter by a factor of about 2.
    #
    # Quasi-Newton minimisers (BFGS, the default) evaluate the objective only at the point in
    # their state (`y_eval`): there it is evaluated here, value and gradient from one compiled
    # function (for the held-out objective: `objectives.held_out_value_and_grad`, the adjoint
    # gradient, cached across calls), and handed to a step compiled once per solver (`_given`).
    # Other solvers step the objective themselves (compiled with it, per call).
    quasi_newton = isinstance(solver, optx.AbstractQuasiNewton)
    if quasi_newton:
        evaluate = _evaluator(
            fn_obj, call, p, nrm, kname, degree, fit_solver, fixed, lo, hi, use_bg
        )
        init = functools.partial(_qn_init, solver)
        step = functools.partial(_qn_step, solver)
        terminate = functools.partial(_qn_terminate, solver)
    else:
        if least_squares:

            def fn(y, args):
                r = call(y, True)
                return jnp.where(jnp.isfinite(r), r, 1e3) / jnp.sqrt(args), None

            f_struct = jax.eval_shape(lambda: fn(y0, 1.0)[0])
        else:

            def fn(y, args):
                return call(y, False) / args, None

            f_struct = jax.ShapeDtypeStruct((), jnp.float64)
        tags = frozenset()
        # Least squares: optimistix's forward-mode Jacobian fed NaN tangents to lineax here
        # (its checks fire inside the vmapped tangent solves), so it uses reverse mode.
        options: dict = {"jac": "bwd"} if least_squares else {"autodiff_mode": "fwd"}
        # Under jit like the steps (Gauss-Newton's init linearises fn; eagerly, lineax's checks
        # then see abstract tangents and fail).
        init = eqx.filter_jit(lambda y, a: solver.init(fn, y, a, options, f_struct, None, tags))
        step = eqx.filter_jit(lambda y, st, a: solver.step(fn, y, a, options, st, tags))
        terminate = eqx.filter_jit(lambda y, st, a: solver.terminate(fn, y, a, options, st, tags))
    scale = jnp.asarray(1.0)

    def step_args(f=None, g=None):
        return (scale, f, g) if quasi_newton else scale

    # Over a background, the held-out objective of a decaying kernel is flat in the offset near
    # the default and lower further out (measured, 2,000 samples, Gaussian: the 7 x 7 grid's best
    # offset was 1x, 1.6x and 4x the default on spot, the bunny and fandisk; BFGS from the
    # default never reached fandisk's). So the start's value and `OFFSET_SCAN` multiples of its
    # offset are evaluated first (value only), and the optimiser starts from the best of them;
    # this takes one of the `max_steps`.
    scanned: list[tuple[dict, float]] = []
    evaluated: list[tuple[float, np.ndarray]] = []
    y_start = y0
    if use_bg and quasi_newton and "offset" in params and int(max_steps) > 1:
        for factor in (1.0, *OFFSET_SCAN):
            y_try = dict(y0, offset=y0["offset"] + np.log(factor))
            f_try, _, per = evaluate(y_try, gradient=False)
            if per is not None:
                evaluated.append((float(f_try), np.asarray(per)))
            scanned.append((y_try, float(f_try)))
        if not np.isfinite(scanned[0][1]):
            raise _not_finite_at_start(obj_name, start)
        y_start = min(scanned, key=lambda t: t[1] if np.isfinite(t[1]) else np.inf)[0]
    bfgs_steps = int(max_steps) - (1 if scanned else 0)
    state = init(y_start, step_args(jnp.zeros(()), y_start))

    def current_f(st):
        info = st.f_info
        if hasattr(info, "f"):
            return float(info.f * scale)
        return float(jnp.sum(info.residual**2) * scale)

    def as_dict(y):
        v = values(y)
        return {k: float(v[k]) for k in params}

    path: list[dict[str, float]] = [dict(as_dict(yy), objective=ff) for yy, ff in scanned]
    best_y, best_f, f0 = y0, np.inf, np.nan
    for yy, ff in scanned:
        if np.isfinite(ff) and ff < best_f:
            best_y, best_f = yy, ff
    if scanned:
        f0 = scanned[0][1]
    y = y_start
    converged, message, steps = False, "", 0
    with progress_bar(bfgs_steps, f"tune {kname}", "step", True if verbose else None) as bar:
        for steps in range(1, bfgs_steps + 1):
            try:
                if quasi_newton:
                    # the last step's gradient would only feed a step that is never taken
                    f_eval, g_eval, per = evaluate(state.y_eval, gradient=steps < bfgs_steps)
                    if per is not None:
                        evaluated.append((float(f_eval), np.asarray(per)))
                    if steps > 1 and np.isfinite(float(f_eval)) and float(f_eval) < best_f:
                        # the best point evaluated, accepted by the line search or not
                        best_y, best_f = state.y_eval, float(f_eval)
                    a = step_args(f_eval, g_eval)
                else:
                    a = step_args()
                y_new, state, _ = step(y, state, a)
            except (eqx.EquinoxRuntimeError, jax.errors.JaxRuntimeError) as e:
                first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
                message = f"the optimiser failed at step {steps}: {first}"
                if steps == 1:
                    raise InputError(
                        f"the {obj_name} objective cannot be evaluated at the starting point "
                        f"{start}: {first}"
                    ) from e
                break
            y = y_new
            done, result = terminate(y, state, a)
            f_acc = current_f(state)
            if steps == 1:
                if not scanned:
                    f0 = f_acc
                if not np.isfinite(f_acc):
                    raise _not_finite_at_start(obj_name, start)
                grad = getattr(state.f_info, "grad", None)
                if grad is not None:
                    g = max(float(jnp.max(jnp.abs(v))) for v in jax.tree.leaves(grad))
                    if np.isfinite(g) and g > 0:
                        scale = jnp.asarray(g / 0.7)
                        state = _rescaled(state, y, scale) or init(
                            y_start, step_args(*(a[1:] if quasi_newton else ()))
                        )
                        done = False
            point = dict(as_dict(y), objective=f_acc)
            path.append(point)
            if np.isfinite(f_acc) and f_acc < best_f:
                best_y, best_f = y, f_acc
            bar.set_postfix(objective=f"{best_f:.4g}")
            bar.update(1)
            if bool(done):
                converged = result == optx.RESULTS.successful
                if not converged:
                    message = f"the optimiser stopped: {optx.RESULTS[result]}"
                break
    if converged:
        message = "converged"
    elif message.startswith("the optimiser failed"):
        pass
    elif not message:
        message = f"stopped after max_steps={max_steps} steps"
    # below rounding (the same point evaluated by the value-only and the gradient programs) is
    # no improvement
    improved = bool(best_f < f0 - 1e-9 * abs(f0))
    se = _standard_error(evaluated, f0, best_f) if improved else np.nan
    if not improved:
        best_y, best_f = y0, f0
        message += "; no better point than the start was found, so the start is returned"
    elif np.isfinite(se) and f0 - best_f <= se:
        message += (
            f"; the best point ({best_f:.5g}) beats the start ({f0:.5g}) by no more than one "
            f"standard error of the held-out error ({se:.2g}), so the start is kept"
        )
        best_y, best_f, improved = y0, f0, False
    kept = best_y is y0  # then the start's own values, not exp(log(.)) of them
    final = dict(fixed, **{k: start[k] if kept else float(v) for k, v in values(best_y).items()})
    c = capped_constraints(p, nrm, final["offset"])
    model = fit(
        c,
        kernel=kname,
        radius=final["radius"],
        smoothing=final["smoothing"],
        degree=degree,
        solver=fit_solver,
        method="dense",
        background=surface_background(p, nrm) if use_bg else None,
    )
    report = TuneReport(
        params=params,
        initial={k: float(start[k]) for k in params},
        final={k: final[k] for k in params},
        initial_objective=f0,
        final_objective=best_f,
        iterations=steps,
        path=path,
        converged=converged,
        improved=improved,
        message=message,
        seconds=time.perf_counter() - t0,
        solver=type(solver).__name__,
        objective=obj_name,
        background=use_bg,
        standard_error=float(se),
    )
    if verbose:
        log(report.summary())
    return model, report


def grid_search(
    points,
    normals,
    *,
    kernel: str | AbstractKernel = "cubic",
    offsets,
    radii=None,
    objective="held-out",
    smoothing: float = 0.0,
    degree: int = 1,
    fit_solver: str = "lu",
    background="auto",
    verbose: bool = False,
) -> tuple[dict[str, float], np.ndarray, float]:
    """Exhaustive search of `objective` over `offsets` x `radii` (radii only for kernels with a
    radius). Each evaluation is one jit-compiled fit (compiled once for the whole grid);
    `background` as for `tune`.

    **Returns:** `(best, table, seconds)`: the best parameters (`offset`, `radius`, `objective`),
    the objective on the grid (len(offsets), len(radii) or 1), and the time taken."""
    t0 = time.perf_counter()
    p, nrm = checked_samples(points, normals)
    cls = type(kernel) if isinstance(kernel, AbstractKernel) else kernel_class(kernel)
    fn_obj, _ = _objective_fn(objective)
    extra = {"background": True} if wants_background(background, cls.name) else {}
    offsets = np.asarray(offsets, dtype=float).ravel()
    if cls.has_radius:
        if radii is None:
            raise InputError(f"the {cls.name} kernel needs `radii` to search over")
        radii = np.asarray(radii, dtype=float).ravel()
    elif radii is not None:
        raise InputError(f"the {cls.name} kernel has no radius; leave `radii` unset")
    for name, arr in (("offsets", offsets), ("radii", radii)):
        if arr is not None and (arr.size == 0 or not np.all(np.isfinite(arr) & (arr > 0))):
            raise InputError(f"`{name}` must be a non-empty list of positive numbers")

    @jax.jit
    def evaluate(d, r):
        return fn_obj(
            p,
            nrm,
            kernel=cls.name,
            offset=d,
            radius=r if cls.has_radius else None,
            smoothing=smoothing,
            degree=degree,
            solver=fit_solver,
            **extra,
        )

    rs = radii if radii is not None else np.array([np.nan])
    table = np.full((len(offsets), len(rs)), np.inf)
    with progress_bar(table.size, f"grid {cls.name}", "fit", True if verbose else None) as bar:
        for i, d in enumerate(offsets):
            for j, r in enumerate(rs):
                table[i, j] = float(evaluate(d, r))
                bar.update(1)
    i, j = np.unravel_index(np.argmin(np.where(np.isfinite(table), table, np.inf)), table.shape)
    best = {"offset": float(offsets[i]), "objective": float(table[i, j])}
    if radii is not None:
        best["radius"] = float(radii[j])
    return best, table, time.perf_counter() - t0


#: Surface samples used by `tune_surface` (and `jaxrbf tune`, `reconstruct --tune`) by default:
#: every objective evaluation is a dense fit, 2,000 samples (6,004 unknowns) about a second.
TUNE_POINTS = 2000


def surface_samples(
    source, normals=None, *, points: int | None = None, sampling: str = "faces", seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """(points, normals) of the surface of `source`: a file path (mesh, point cloud with normals,
    2-D polyline) or an array of points (then `normals` is required). Meshes are sampled
    (`points`, default `TUNE_POINTS`; `sampling` `faces` or `vertices`); point clouds are
    subsampled to `points` (default `TUNE_POINTS`). Host."""
    import os

    from . import io
    from ._prepare import check_not_flat, polyline_normals, sample_faces, vertex_normals
    from ._reconstruct import _subsample

    k = TUNE_POINTS if points is None else int(points)
    if k < 1:
        raise InputError(f"`points` must be a positive number, got {points}")
    if isinstance(source, (str, os.PathLike)):
        data = io.read_input(source)
        name = os.fspath(source)
    else:
        if normals is None:
            raise InputError("`normals` are needed with an array of points (one per point)")
        data = io.PointCloud(io.as_points(source, "points"), np.asarray(normals, dtype=float))
        name = "the points"
    if isinstance(data, io.Mesh):
        v, f = data.vertices, data.faces.astype(np.int64)
        check_not_flat(v, f"vertices of {name}")
        if sampling == "faces":
            return sample_faces(v, f, k, seed)
        if sampling != "vertices":
            raise InputError(f"`sampling` must be 'faces' or 'vertices', got {sampling!r}")
        vn = vertex_normals(v, f)
        used = np.zeros(len(v), dtype=bool)
        used[f.ravel()] = True
        used &= np.linalg.norm(vn, axis=1) > 0
        return _subsample(v[used], vn[used], k, seed)
    if isinstance(data, io.Polyline):
        vv = data.vertices
        return _subsample(vv, polyline_normals(vv, data.closed), k, seed)
    if data.normals is None:
        raise InputError(
            f"{name} has points but no normals; give nx, ny, nz columns (or a mesh) so that "
            "inside and outside are known"
        )
    check_not_flat(data.points, f"points of {name}")
    return _subsample(data.points, data.normals, k, seed)


def tune_surface(
    source,
    normals=None,
    *,
    kernel: str | None = None,
    params=None,
    objective="held-out",
    solver=None,
    offset: float | None = None,
    radius: float | None = None,
    smoothing: float = 0.0,
    degree: int = 1,
    points: int | None = None,
    sampling: str = "faces",
    seed: int = 0,
    max_steps: int = 4,
    verbose: bool = False,
):
    """`tune` on the surface samples of `source` (see `surface_samples`), with `offset` and
    `radius` as fractions of the bounding-box diagonal (as on the command line). `kernel`
    defaults to cubic (3-D) or thin-plate (2-D); `params` to offset and, for kernels with one,
    radius. Returns `(model, report)`."""
    from ._prepare import diagonal

    p, n = surface_samples(source, normals, points=points, sampling=sampling, seed=seed)
    if kernel is None:
        kernel = "cubic" if p.shape[1] == 3 else "thin-plate"
    cls = kernel_class(kernel)
    if params is None:
        params = ("offset", "radius") if cls.has_radius else ("offset",)
    diag = diagonal(p)
    for name, value in (("offset", offset), ("radius", radius)):
        if value is not None and not (np.isfinite(value) and value > 0):
            raise InputError(f"`{name}` must be a positive fraction of the diagonal, got {value!r}")
    if verbose:
        log(f"tuning {', '.join(params)} of the {cls.name} kernel on {len(p):,} surface samples")
    return tune(
        p,
        n,
        kernel=cls.name,
        params=params,
        objective=objective,
        solver=solver,
        offset=None if offset is None else offset * diag,
        radius=None if radius is None else radius * diag,
        smoothing=smoothing,
        degree=degree,
        max_steps=max_steps,
        verbose=verbose,
    )
