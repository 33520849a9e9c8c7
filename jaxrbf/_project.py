"""Newton projection of points onto a level set of any implicit, with the gradient from JAX."""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._model import map_blocks

_ROWS = 4096


def value_and_gradient(implicit: Callable, points) -> tuple[jax.Array, jax.Array]:
    """f and grad f at `points` (n, d) for any implicit that maps (n, d) points to (n,) values
    independently per point; in fixed-size blocks. The gradient comes from `jax.vjp`."""

    def block(p):
        vals, pullback = jax.vjp(implicit, p)
        return vals, pullback(jnp.ones_like(vals))[0]

    p = jnp.asarray(points)
    both = map_blocks(
        lambda b: jnp.concatenate([x.reshape(b.shape[0], -1) for x in block(b)], 1), p, _ROWS
    )
    return both[:, 0], both[:, 1:]


@eqx.filter_jit
def _newton(implicit, points, level, steps: int, max_step):
    def body(_, x):
        f, g = value_and_gradient(implicit, x)
        g2 = jnp.sum(g * g, axis=1)
        step = jnp.where(g2 > 0, (f - level) / jnp.where(g2 > 0, g2, 1.0), 0.0)[:, None] * g
        length = jnp.linalg.norm(step, axis=1, keepdims=True)
        step = step * jnp.minimum(1.0, max_step / jnp.maximum(length, 1e-300))
        return x - step

    x = jax.lax.fori_loop(0, steps, body, points)
    f, g = value_and_gradient(implicit, x)
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
    x, f, g = _newton(implicit, jnp.asarray(p), float(level), int(steps), max_step)
    gnorm = jnp.linalg.norm(g, axis=1)
    dist = jnp.abs(f - level) / jnp.where(gnorm > 0, gnorm, jnp.nan)
    converged = np.asarray(jnp.isfinite(dist) & (dist <= tol))
    return np.asarray(x), converged
