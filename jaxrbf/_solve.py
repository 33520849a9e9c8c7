"""Solvers for the saddle-point system: LU, Cholesky (null-space form), and preconditioned CG and
GMRES.

Precision: every solve runs in float64. The saddle systems of r^3 and r^2 log r kernels are badly
conditioned (the condition number grows with the number and density of points), and float32 loses
the constraints entirely beyond a few hundred points.

Null-space form (Cholesky, CG, GMRES). With the sign conventions of `jaxrbf.kernels`, A is positive
definite on the null space of P^T. Let P = Q1 R (thin QR) and Pi = I - Q1 Q1^T. Then

    C = Pi (A + s I) Pi + Q1 Q1^T

is symmetric positive definite on all of R^n, and C w = Pi h gives exactly the w of the saddle system
(w lies in null(P^T), Pi (A + s I) w = Pi h); the polynomial follows from R a = Q1^T (h - (A + s I) w).
Forming C costs O(n^2 k), not the O(n^3) of an explicit null-space basis.

Iterative solvers (CG on the stored C, GMRES matrix-free) are preconditioned by two-level additive
Schwarz (`jaxrbf._schwarz`): for overlapping subdomains s (and a coarse subset of the centres)

    M^-1 v = sum_s R_s^T W_s R_s v + Q1 Q1^T v

where W_s is the top-left block of the inverse of the subdomain's own saddle matrix
[[A_s + s I, P_s], [P_s^T, 0]] (its local RBF interpolation, with its own polynomial). W_s maps
local data to local weights that satisfy P_s^T w = 0, so every term lies in null(P^T), and C acts as
the identity on span(Q1), hence the last term. M^-1 is symmetric positive semi-definite, as CG
requires. The local inverses are formed once, batched over subdomains, so applying M^-1 costs a few
small matrix-vector products.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
from jax import lax
from jaxtyping import Array

from ._model import poly_basis
from ._system import kernel_matrix, kernel_matvec, saddle_matrix, saddle_matvec
from .kernels import AbstractKernel

SOLVERS = ("lu", "cholesky", "cg", "gmres")


class Solution(NamedTuple):
    weights: Array
    coeffs: Array
    residual: Array  # max |B x - rhs| / max |rhs|
    ok: Array  # lineax reported success
    steps: Array  # CG iterations or GMRES restart cycles (0 for the direct solvers)


def _projector(p: Array) -> tuple[Array, Array]:
    q1, r = jnp.linalg.qr(p, mode="reduced")
    return q1, r


def _poly_from_residual(q1, r, h, aw):
    if q1.shape[1] == 0:
        return jnp.zeros((0,), dtype=h.dtype)
    return jax.scipy.linalg.solve_triangular(r, q1.T @ (h - aw), lower=False)


def _null_space_matrix(a_mat: Array, q1: Array) -> Array:
    """C = Pi A Pi + Q1 Q1^T for symmetric A, as A plus a rank-2k update written element by element.

    With M = A Q1 and T = Q1^T M, C = A - M Q1^T - Q1 M^T + Q1 (T + I) Q1^T = A + U Q1^T + Q1 U^T
    where U = Q1 (T + I) / 2 - M (T symmetrised). The update is a sum of k outer products of
    vectors, which XLA fuses into one elementwise pass that can overwrite A in place: no n x n
    temporaries besides A itself. Each term u_i q_j + q_i u_j is exactly symmetric in i, j."""
    m = a_mat @ q1
    t = q1.T @ m
    t = 0.5 * (t + t.T) + jnp.eye(q1.shape[1], dtype=q1.dtype)
    u = 0.5 * (q1 @ t) - m
    c_mat = a_mat
    for col in range(q1.shape[1]):
        c_mat = c_mat + (u[:, col, None] * q1[None, :, col] + q1[:, col, None] * u[None, :, col])
    return c_mat


def _residual(kernel, centres, degree, smoothing, h, w, a) -> Array:
    top, bottom = saddle_matvec(kernel, centres, degree, smoothing, w, a)
    err = jnp.maximum(jnp.max(jnp.abs(top - h)), jnp.max(jnp.abs(bottom), initial=0.0))
    return err / jnp.maximum(jnp.max(jnp.abs(h)), jnp.finfo(h.dtype).tiny)


class _PCG(lx.AbstractLinearSolver):
    """Preconditioned conjugate gradients that stops on max|r| <= tol * max|b|.

    lineax's `CG` scales its tolerance element by element (|r_i| against rtol |b_i|), which never
    converges where b has (near-)zero entries, as the on-surface values here do, and it also asks
    for small steps in the solution, which a badly conditioned system need not give. Written as a
    lineax solver, so `linear_solve` still differentiates through it (the operator is symmetric,
    so its transpose is itself).

    The residual is the recursive one, never replaced by b - C y: with weights of 1e8 and more, the
    explicit residual carries a rounding error near 1e-9 relative, and putting it back into the
    recurrence breaks the conjugacy (measured: the residual stalls at 1e-6, then grows), while
    the recursive one keeps converging and the true residual settles at that rounding floor.
    The caller checks the true residual."""

    tol: float
    max_steps: int

    def init(self, operator, options):
        return operator

    def compute(self, state, vector, options):
        op = state
        pre = options.get("preconditioner")
        apply_pre = (lambda r: r) if pre is None else pre.mv
        b = vector
        target = self.tol * jnp.max(jnp.abs(b))

        def cond(c):
            _, r, _, gamma, step = c
            return (step < self.max_steps) & (jnp.max(jnp.abs(r)) > target) & (gamma > 0)

        def body(c):
            y, r, p, gamma, step = c
            ap = op.mv(p)
            alpha = gamma / jnp.vdot(p, ap)
            r = r - alpha * ap
            z = apply_pre(r)
            gamma_new = jnp.vdot(r, z)
            return y + alpha * p, r, z + (gamma_new / gamma) * p, gamma_new, step + 1

        z0 = apply_pre(b)
        init = (jnp.zeros_like(b), b, z0, jnp.vdot(b, z0), jnp.array(0))
        y, r, _, _, steps = lax.while_loop(cond, body, init)
        done = jnp.max(jnp.abs(r)) <= target
        result = lx.RESULTS.where(done, lx.RESULTS.successful, lx.RESULTS.max_steps_reached)
        return y, result, {"num_steps": steps}

    def transpose(self, state, options):
        out = dict(options)
        if "preconditioner" in options:
            out["preconditioner"] = options["preconditioner"].transpose()
        return state.transpose(), out

    def conj(self, state, options):
        return state, options

    def assume_full_rank(self):
        return True


def _local_inverses(kernel, xs: Array, mask: Array, degree: int, smoothing) -> Array:
    """W_s for every subdomain: xs (s, m, d) padded centres, mask (s, m), smoothing (s, m) (each
    row's). Returns (s, m, m)."""

    def one(x, keep, sm):
        m = x.shape[0]
        both = keep[:, None] & keep[None, :]
        a = jnp.where(both, kernel_matrix(kernel, x, sm), 0.0) + jnp.diag(~keep).astype(x.dtype)
        # The local polynomial on centred, rescaled coordinates: same span, better conditioned.
        w = keep.astype(x.dtype)[:, None]
        mid = jnp.sum(x * w, axis=0) / jnp.maximum(jnp.sum(w), 1.0)
        ext = jnp.max(jnp.where(keep[:, None], jnp.abs(x - mid), 0.0))
        p = poly_basis((x - mid) / jnp.maximum(ext, 1e-300), degree) * w
        k = p.shape[1]
        b = jnp.block([[a, p], [p.T, jnp.zeros((k, k), x.dtype)]]) if k else a
        inv = jnp.linalg.inv(b)[:m, :m]
        return 0.5 * (inv + inv.T) * both

    return jax.vmap(one)(xs, mask, smoothing)


def schwarz_preconditioner(kernel, centres, degree, smoothing, decomposition, q1):
    """The two-level additive Schwarz M^-1 of the module docstring, as a function of v."""
    idx, mask, coarse = decomposition
    rows = jnp.broadcast_to(smoothing, centres.shape[:1])  # a scalar, or one per row
    w_loc = _local_inverses(kernel, centres[idx], mask, degree, rows[idx])
    has_coarse = coarse.shape[0] > 0
    if has_coarse:
        whole = jnp.ones((1, coarse.shape[0]), bool)
        w_c = _local_inverses(kernel, centres[coarse][None], whole, degree, rows[coarse][None])[0]

    def apply(v):
        ys = jnp.einsum("smk,sk->sm", w_loc, v[idx] * mask)
        out = jnp.zeros_like(v).at[idx].add(ys)
        if has_coarse:
            out = out.at[coarse].add(w_c @ v[coarse])
        return out + q1 @ (q1.T @ v)

    return apply


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
    decomposition: tuple[Array, Array, Array] | None = None,
    stored: bool = True,
) -> Solution:
    """Solve eq. 6 for the weights and polynomial coefficients.

    **Arguments:**
    - `kernel`, `centres` (n, d) normalised, `values` (n,), `smoothing` (>= 0: a scalar, or
      (n,), one per row).
    - `degree`: -1, 0 or 1. `solver`: one of `SOLVERS`.
    - `rtol`, `max_steps`: for CG and GMRES (`max_steps` in iterations; default
      min(20 n, 5000)). CG stops on max|r| <= rtol max|b|; GMRES on lineax's criterion.
    - `decomposition`: (idx, mask, coarse) from `jaxrbf._schwarz.decompose`, for the Schwarz
      preconditioner of CG and GMRES; None solves without one.
    - `stored`: CG keeps the n x n null-space matrix (fast matvecs, O(n^2) memory); False applies
      it block by block, as GMRES always does.

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

        def stored_operator():
            a_mat = kernel_matrix(kernel, centres, smoothing)
            c_mat = _null_space_matrix(a_mat, q1) if k else a_mat
            return lx.MatrixLinearOperator(c_mat, lx.positive_semidefinite_tag)

        if solver == "cholesky":
            op = stored_operator()
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
            vec = jax.ShapeDtypeStruct((n,), h.dtype)
            if solver == "cg" and stored:
                op = stored_operator()
            else:

                def c_apply(v):
                    av = kernel_matvec(kernel, centres, project(v), smoothing)
                    return project(av) + q1 @ (q1.T @ v)

                op = lx.FunctionLinearOperator(c_apply, vec, lx.positive_semidefinite_tag)
            pre = None
            if decomposition is not None:
                pre = schwarz_preconditioner(kernel, centres, degree, smoothing, decomposition, q1)
            cap = max_steps if max_steps is not None else min(20 * n, 5000)
            if solver == "cg":
                options = {}
                if pre is not None:
                    options["preconditioner"] = lx.FunctionLinearOperator(
                        pre, vec, lx.positive_semidefinite_tag
                    )
                sol = lx.linear_solve(
                    op, project(h), _PCG(tol=rtol, max_steps=cap), options=options, throw=False
                )
                w = project(sol.value)
            else:
                # Right preconditioning, C M u = b with w = M u: GMRES then measures the true
                # residual, and u ~ b in size, so one absolute tolerance (rtol max|b|) suits both
                # of lineax's checks (on the residual and on the step in u); its element-wise
                # relative test never passes where b has near-zero entries.
                right = (
                    op if pre is None else lx.FunctionLinearOperator(lambda u: op.mv(pre(u)), vec)
                )
                # lineax counts GMRES steps in restart cycles; `max_steps` is in iterations.
                restart = max(1, min(n, 100, cap))
                atol = rtol * jnp.max(jnp.abs(h))
                it = lx.GMRES(rtol=0.0, atol=atol, max_steps=-(-cap // restart), restart=restart)
                sol = lx.linear_solve(right, project(h), it, throw=False)
                w = project(sol.value if pre is None else pre(sol.value))
            steps = sol.stats.get("num_steps", jnp.array(0))
            result = sol.result
        a = _poly_from_residual(q1, r, h, kernel_matvec(kernel, centres, w, smoothing))
        ok = result == lx.RESULTS.successful
    res = _residual(kernel, centres, degree, smoothing, h, w, a)
    return Solution(w, a, res, ok, jnp.asarray(steps))
