"""The saddle-point system of the paper's eq. 6-8, dense and matrix-free.

    B [w; a] = [h; 0],   B = [[A + s I, P], [P^T, 0]],   A_ij = phi(|c_i - c_j|),   P_i = p(c_i)

`s` is the smoothing parameter (0 interpolates). The dense form stores B (O(n^2) memory); the
matrix-free form applies A in fixed-size row blocks (O(block * n) memory) and never stores it.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from ._model import block_rows, kernel_block, map_blocks, poly_basis
from .kernels import AbstractKernel


def kernel_matrix(kernel: AbstractKernel, centres: Array, smoothing) -> Float[Array, "n n"]:
    """A + s I, dense (`smoothing` s a scalar, or one per row: A + diag(s))."""
    n = centres.shape[0]
    return kernel_block(kernel, centres, centres) + smoothing * jnp.eye(n, dtype=centres.dtype)


def saddle_matrix(kernel: AbstractKernel, centres: Array, degree: int, smoothing) -> Array:
    """B of eq. 8, dense. Written as a sum of zero-padded blocks (not concatenations) so that XLA
    fuses it into one pass writing a single (n + k)^2 buffer, with no intermediate n x n copy."""
    n = centres.shape[0]
    p = poly_basis(centres, degree)
    k = p.shape[1]
    a = kernel_matrix(kernel, centres, smoothing)
    if k == 0:
        return a
    return (
        jnp.pad(a, ((0, k), (0, k))) + jnp.pad(p, ((0, k), (n, 0))) + jnp.pad(p.T, ((n, 0), (0, k)))
    )


def kernel_matvec(kernel: AbstractKernel, centres: Array, v: Array, smoothing) -> Array:
    """(A + s I) v, block by block: A is never stored."""
    rows = block_rows(centres.shape[0])
    av = map_blocks(lambda xb: kernel_block(kernel, xb, centres) @ v, centres, rows)
    return av + smoothing * v


def saddle_matvec(
    kernel, centres, degree: int, smoothing, w: Array, a: Array
) -> tuple[Array, Array]:
    """B [w; a], matrix-free."""
    p = poly_basis(centres, degree)
    return kernel_matvec(kernel, centres, w, smoothing) + p @ a, p.T @ w


def rounding_floor(kernel, centres, degree: int, smoothing, w: Array, a: Array, h: Array) -> Array:
    """The relative residual max|B [w; a] - rhs| / max|rhs| that float64 rounding alone may leave
    when B [w; a] is evaluated: sqrt(n) eps max(|A| |w| + |P| |a|) / max|h| (each of the n terms
    of a row rounds by eps of its size, and independent roundings add up as sqrt(n); the
    worst case is n). Large weights of an ill-conditioned system put it above a fixed tolerance
    however exact the solve: 1,148 samples of the beetle's 33 open pieces, weights up to 2e6,
    read 1.4e-7 x sqrt(n) = 8e-6, and CG left 1.4e-6, LU 7.3e-7."""
    rows = block_rows(centres.shape[0])
    aw = map_blocks(
        lambda xb: jnp.abs(kernel_block(kernel, xb, centres)) @ jnp.abs(w), centres, rows
    )
    aw = aw + jnp.abs(smoothing) * jnp.abs(w) + jnp.abs(poly_basis(centres, degree)) @ jnp.abs(a)
    eps = jnp.finfo(h.dtype).eps
    n = centres.shape[0]
    return (
        jnp.sqrt(n) * eps * jnp.max(aw) / jnp.maximum(jnp.max(jnp.abs(h)), jnp.finfo(h.dtype).tiny)
    )
