"""Newton projection of points onto a level set of any implicit, with the gradient from JAX."""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._model import forward_value_and_gradient, map_blocks

_ROWS = 4096


def value_and_gradient(implicit: Callable, points) -> tuple[jax.Array, jax.Array]:
    """f and grad f at `points` (n, d) for any implicit that maps (n, d) points to (n,) values
    independently per point. A jaxrbf model answers with its own `value_and_gradient` (analytic
    for RBF models, patch by patch for large concrete inputs to a partition of unity); any other
    callable gets one forward-mode derivative per coordinate (`jax.jvp`) in fixed-size blocks,
    whose memory stays that of one evaluation (reverse mode would keep every intermediate)."""
    own = getattr(implicit, "value_and_gradient", None)
    if own is not None:
        return own(points)

    def block(p):
        f, g = forward_value_and_gradient(implicit, p)
        return jnp.concatenate([f[:, None], g], 1)

    both = map_blocks(block, jnp.asarray(points), _ROWS)
    return both[:, 0], both[:, 1:]


def _newton_step(x, f, g, level, max_step, xp=jnp):
    """One Newton step x - (f - level) g / |g|^2 per row, at most `max_step` long. `xp`: the array
    namespace (`numpy` for host arrays: eager JAX compiles each op anew for every new row count,
    and the host-driven loops below shrink their rows every step)."""
    g2 = xp.sum(g * g, axis=1)
    step = xp.where(g2 > 0, (f - level) / xp.where(g2 > 0, g2, 1.0), 0.0)[:, None] * g
    length = xp.linalg.norm(step, axis=1, keepdims=True)
    return x - step * xp.minimum(1.0, max_step / xp.maximum(length, 1e-300))


@eqx.filter_jit
def _newton(implicit, points, level, steps: int, max_step):
    def body(_, x):
        f, g = value_and_gradient(implicit, x)
        return _newton_step(x, f, g, level, max_step)

    x = jax.lax.fori_loop(0, steps, body, points)
    f, g = value_and_gradient(implicit, x)
    return x, f, g


def _newton_host(implicit, points, level, steps: int, max_step, tol):
    """The same iteration driven from the host, for models with their own bulk
    `value_and_gradient` (a partition of unity evaluates many concrete points patch by patch, far
    faster than inside one traced loop); a point stops moving once its distance estimate is at
    round-off level (a millionth of `tol`)."""
    x = np.array(points, dtype=float)
    f, g = (np.array(a, dtype=float) for a in implicit.value_and_gradient(x))
    live = np.arange(len(x))
    for _ in range(steps):
        gn = np.linalg.norm(g[live], axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            done = np.abs(f[live] - level) / gn <= 1e-6 * tol  # at round-off: stop moving
        live = live[~done]
        if len(live) == 0:
            break
        x[live] = _newton_step(x[live], f[live], g[live], level, max_step, np)
        fl, gl = implicit.value_and_gradient(x[live])
        f[live], g[live] = np.asarray(fl), np.asarray(gl)
    return x, f, g


def project(
    implicit: Callable,
    points,
    *,
    level: float = 0.0,
    steps: int = 10,
    max_step: float | None = None,
    tol: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Move points onto f = `level` by Newton steps along the gradient, x <- x - (f - level) g / |g|^2.

    **Arguments:**
    - `implicit`: any JAX-traceable callable mapping (n, d) points to (n,) values.
    - `points`: (n, d) starting points.
    - `steps`: Newton iterations. `max_step`: longest move per step (default: 1% of the points'
      bounding-box diagonal), which keeps a point from jumping to another sheet of the surface.
    - `tol`: a point has converged when its distance estimate |f - level| / |grad f| is below this
      (default 1e-6 of the diagonal).

    **Returns:** `(projected, converged)`: the moved points (n, d) and a boolean mask (n,).
    """
    p = np.asarray(points, dtype=float)
    diag = float(np.linalg.norm(np.ptp(p, axis=0))) if len(p) > 1 else 1.0
    diag = diag if diag > 0 else 1.0
    max_step = 0.01 * diag if max_step is None else float(max_step)
    tol = 1e-6 * diag if tol is None else float(tol)
    if hasattr(implicit, "value_and_gradient"):
        x, f, g = _newton_host(implicit, p, float(level), int(steps), max_step, tol)
    else:
        x, f, g = (
            np.asarray(a)
            for a in _newton(implicit, jnp.asarray(p), float(level), int(steps), max_step)
        )
    gnorm = np.linalg.norm(g, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        dist = np.abs(f - level) / np.where(gnorm > 0, gnorm, np.nan)
    converged = np.isfinite(dist) & (dist <= tol)
    return x, converged
