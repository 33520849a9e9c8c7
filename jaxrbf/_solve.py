"""Solvers for the saddle-point system: LU, Cholesky (null-space form) and matrix-free GMRES.

Precision: every solve runs in float64. The saddle systems of r^3 and r^2 log r kernels are badly
conditioned (the condition number grows with the number and density of points), and float32 loses
the constraints entirely beyond a few hundred points.

Null-space form (Cholesky, GMRES). With the sign conventions of `jaxrbf.kernels`, A is positive
definite on the null space of P^T. Let P = Q1 R (thin QR) and Pi = I - Q1 Q1^T. Then

    C = Pi (A + s I) Pi + Q1 Q1^T

is symmetric positive definite on all of R^n, and C w = Pi h gives exactly the w of the saddle system
(w lies in null(P^T), Pi (A + s I) w = Pi h); the polynomial follows from R a = Q1^T (h - (A + s I) w).
Forming C costs O(n^2 k), not the O(n^3) of an explicit null-space basis.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
from jaxtyping import Array

from ._model import poly_basis
from ._system import kernel_matrix, kernel_matvec, saddle_matrix, saddle_matvec
from .kernels import AbstractKernel

SOLVERS = ("lu", "cholesky", "gmres")


class Solution(NamedTuple):
    weights: Array
    coeffs: Array
    residual: Array  # max |B x - rhs| / max |rhs|
    ok: Array  # lineax reported success
    steps: Array  # restart cycles of GMRES (up to 100 iterations each; 0 for direct solvers)


def _projector(p: Array) -> tuple[Array, Array]:
    q1, r = jnp.linalg.qr(p, mode="reduced")
    return q1, r


def _poly_from_residual(q1, r, h, aw):
    if q1.shape[1] == 0:
        return jnp.zeros((0,), dtype=h.dtype)
    return jax.scipy.linalg.solve_triangular(r, q1.T @ (h - aw), lower=False)


def _residual(kernel, centres, degree, smoothing, h, w, a) -> Array:
    top, bottom = saddle_matvec(kernel, centres, degree, smoothing, w, a)
    err = jnp.maximum(jnp.max(jnp.abs(top - h)), jnp.max(jnp.abs(bottom), initial=0.0))
    return err / jnp.maximum(jnp.max(jnp.abs(h)), jnp.finfo(h.dtype).tiny)


@eqx.filter_jit
def solve_system(
    kernel: AbstractKernel,
    centres: Array,
    values: Array,
    smoothing: Array,
    degree: int,
    solver: str,
    rtol: float = 1e-11,
    max_steps: int | None = None,
) -> Solution:
    """Solve eq. 6 for the weights and polynomial coefficients.

    **Arguments:**
    - `kernel`, `centres` (n, d) normalised, `values` (n,), `smoothing` (scalar >= 0).
    - `degree`: -1, 0 or 1. `solver`: one of `SOLVERS`.
    - `rtol`, `max_steps`: for GMRES (`max_steps` in iterations; default min(20 n, 5000)).

    **Returns:** a `Solution`; the caller checks `ok` and `residual`.
    """
    n = centres.shape[0]
    p = poly_basis(centres, degree)
    k = p.shape[1]
    h = values
    steps = jnp.array(0)
    if solver == "lu":
        b = saddle_matrix(kernel, centres, degree, smoothing)
        rhs = jnp.concatenate([h, jnp.zeros((k,), h.dtype)])
        sol = lx.linear_solve(lx.MatrixLinearOperator(b), rhs, lx.LU(), throw=False)
        w, a = sol.value[:n], sol.value[n:]
        ok = sol.result == lx.RESULTS.successful
    else:
        q1, r = _projector(p)

        def project(v):
            return v - q1 @ (q1.T @ v)

        if solver == "cholesky":
            a_mat = kernel_matrix(kernel, centres, smoothing)
            if k:
                # C = Pi A Pi + Q1 Q1^T, with the rank-k updates fused into the n x n passes
                left = a_mat - q1 @ (q1.T @ a_mat)
                c_mat = left - (left @ q1) @ q1.T + q1 @ q1.T
            else:
                c_mat = a_mat
            op = lx.MatrixLinearOperator(c_mat, lx.positive_semidefinite_tag)
            chol = lx.Cholesky()
            state = chol.init(op, {})
            sol = lx.linear_solve(op, project(h), chol, state=state, throw=False)
            w = project(sol.value)
            # One step of iterative refinement against the un-formed operator (an O(n^2) matvec
            # in float64, reusing the factor): it removes the error that forming C introduces.
            resid = project(h - kernel_matvec(kernel, centres, w, smoothing))
            fix = lx.linear_solve(op, resid, chol, state=state, throw=False)
            w, result = w + project(fix.value), fix.result
        else:

            def c_apply(v):
                av = kernel_matvec(kernel, centres, project(v), smoothing)
                return project(av) + q1 @ (q1.T @ v)

            op = lx.FunctionLinearOperator(
                c_apply, jax.ShapeDtypeStruct((n,), h.dtype), lx.positive_semidefinite_tag
            )
            # lineax counts GMRES steps in restart cycles; `max_steps` is in iterations.
            cap = max_steps if max_steps is not None else min(20 * n, 5000)
            restart = max(1, min(n, 100, cap))
            # CG was tried and stalls on these ill-conditioned systems; restarted GMRES does not.
            it = lx.GMRES(rtol=rtol, atol=0.0, max_steps=-(-cap // restart), restart=restart)
            sol = lx.linear_solve(op, project(h), it, throw=False)
            steps = sol.stats.get("num_steps", jnp.array(0))
            w, result = sol.value, sol.result
        a = _poly_from_residual(q1, r, h, kernel_matvec(kernel, centres, w, smoothing))
        ok = result == lx.RESULTS.successful
    res = _residual(kernel, centres, degree, smoothing, h, w, a)
    return Solution(w, a, res, ok, jnp.asarray(steps))
