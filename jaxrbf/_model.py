"""The fitted RBF model: an equinox pytree that evaluates f, its gradient and the unit normal."""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._errors import InputError
from .kernels import AbstractKernel

# Elements of one (rows x centres) kernel block: 2**21 float64 = 16 MiB, whatever the input size.
_BLOCK_ELEMENTS = 2**21


def block_rows(n_centres: int) -> int:
    """Rows of a kernel block for `n_centres` columns: a power of two in [16, 4096]."""
    rows = max(16, min(4096, _BLOCK_ELEMENTS // max(n_centres, 1)))
    return 1 << (rows.bit_length() - 1)


def pairwise_sq(x: Float[Array, "b d"], c: Float[Array, "m d"]) -> Float[Array, "b m"]:
    """Squared distances, one coordinate at a time (faster than broadcasting a (b, m, d) array and
    more accurate than the Gram form |x|^2 + |c|^2 - 2 x.c)."""
    r2 = jnp.zeros((x.shape[0], c.shape[0]), dtype=jnp.result_type(x, c))
    for k in range(x.shape[1]):
        r2 = r2 + (x[:, k, None] - c[None, :, k]) ** 2
    return r2


def kernel_block(kernel: AbstractKernel, x: Array, c: Array) -> Array:
    return kernel.from_r2(pairwise_sq(x, c))


def n_poly(degree: int, dim: int) -> int:
    """Number of polynomial terms: 0 (no polynomial), 1 (constant) or 1 + dim (linear)."""
    return {-1: 0, 0: 1, 1: 1 + dim}[degree]


def poly_basis(x: Float[Array, "n d"], degree: int) -> Float[Array, "n k"]:
    """The monomials [1, x_1, ..., x_d] (degree 1), [1] (degree 0) or none (degree -1)."""
    ones = jnp.ones((x.shape[0], 1), dtype=x.dtype)
    if degree < 0:
        return jnp.zeros((x.shape[0], 0), dtype=x.dtype)
    if degree == 0:
        return ones
    return jnp.concatenate([ones, x], axis=1)


def forward_value_and_gradient(fn: Callable[[Array], Array], x: Float[Array, "b d"]):
    """f and grad f at points `x` (b, d) of a row-wise `fn`, from one forward-mode derivative
    per coordinate (`jax.jvp`): memory stays that of one evaluation, where reverse mode would
    keep every intermediate for its backward pass. Returns shapes (b,) and (b, d)."""
    cols = []
    f = None
    for e in jnp.eye(x.shape[1], dtype=x.dtype):
        f, df = jax.jvp(fn, (x,), (jnp.broadcast_to(e, x.shape),))
        cols.append(df.reshape(-1))
    return f.reshape(-1), jnp.stack(cols, axis=1)


def map_blocks(fn: Callable[[Array], Array], x: Float[Array, "n d"], rows: int) -> Array:
    """Apply `fn` to fixed-size row blocks of `x` (the last one padded) and join the results.

    The block size is fixed, so memory is bounded for any `n` and the compiled block is reused.
    """
    n = x.shape[0]
    if n <= rows:
        return fn(x)
    nb = -(-n // rows)
    pad = nb * rows - n
    xp = jnp.concatenate([x, jnp.broadcast_to(x[:1], (pad,) + x.shape[1:])]) if pad else x
    out = jax.lax.map(fn, xp.reshape((nb, rows) + x.shape[1:]))
    return out.reshape((nb * rows,) + out.shape[2:])[:n]


class AbstractModel(eqx.Module):
    """What every fitted implicit shares: evaluation in the user's units through a normalising
    transform x' = (x - shift) / scale, in fixed-size blocks (memory bounded for any number of
    points), with gradients (analytic or forward-mode) and unit normals.

    Subclasses hold `shift`, `scale` and `residual` fields and implement `_eval_normalised`
    (values at a block of normalised points), `_block_rows` (the block size) and `bounds`.
    """

    shift: eqx.AbstractVar[Float[Array, " d"]]
    scale: eqx.AbstractVar[Float[Array, ""]]
    residual: eqx.AbstractVar[Float[Array, ""]]

    @property
    def dim(self) -> int:
        return self.shift.shape[0]

    def normalise(self, x: Array) -> Array:
        return (x - self.shift) / self.scale

    def _eval_normalised(self, xn: Float[Array, "b d"]) -> Float[Array, " b"]:
        raise NotImplementedError

    def _value_grad_normalised(
        self, xn: Float[Array, "b d"]
    ) -> tuple[Float[Array, " b"], Float[Array, "b d"]]:
        """f and its gradient with respect to the normalised coordinates at a block `xn`. Default:
        one forward-mode derivative per coordinate (`jax.jvp`), whose memory stays that of one
        evaluation (reverse mode would keep every intermediate of the block for its backward
        pass); subclasses with a closed form override it."""
        return forward_value_and_gradient(self._eval_normalised, xn)

    def _block_rows(self) -> int:
        raise NotImplementedError

    def bounds(self) -> tuple[Array, Array]:
        raise NotImplementedError

    def _flat(self, x: ArrayLike) -> tuple[Array, tuple[int, ...]]:
        x = jnp.asarray(x)
        if x.ndim < 1 or x.shape[-1] != self.dim:
            raise InputError(
                f"points must have shape (..., {self.dim}) for this {self.dim}-D model, got {x.shape}"
            )
        return x.reshape(-1, self.dim).astype(self.shift.dtype), x.shape[:-1]

    def _dispatch(self, fn, flat: Array) -> Array:
        """`fn(self, flat)`: inside the caller's trace when anything is traced, else split over
        the devices (`jaxrbf._sharding`). No points give an empty result of the right shape (a
        partition model's local fits would otherwise reshape an empty batch)."""
        if flat.shape[0] == 0:
            return self._dispatch(fn, jnp.zeros((1, self.dim), flat.dtype))[:0]
        if _traced(self, flat):
            return fn(self, flat)
        from ._sharding import split_over_devices

        return jnp.asarray(split_over_devices(lambda f: fn(self, f), flat))

    def __call__(self, x: Float[ArrayLike, "... d"]) -> Float[Array, "..."]:
        """f at points `x` of shape (..., d); returns shape (...)."""
        flat, lead = self._flat(x)
        return self._dispatch(_values, flat).reshape(lead)

    def gradient(self, x: Float[ArrayLike, "... d"]) -> Float[Array, "... d"]:
        """grad f at `x` (in the user's units; analytic for an `RBFModel`, forward-mode JAX
        otherwise; differentiable again); shape (..., d)."""
        return self.value_and_gradient(x)[1]

    def value_and_gradient(
        self, x: Float[ArrayLike, "... d"]
    ) -> tuple[Float[Array, "..."], Float[Array, "... d"]]:
        """f and grad f at `x` in one pass (cheaper than calling the model and `gradient`);
        shapes (...) and (..., d)."""
        flat, lead = self._flat(x)
        fg = self._dispatch(_values_gradients, flat)
        return fg[:, 0].reshape(lead), fg[:, 1:].reshape(lead + (self.dim,))

    def normal(self, x: Float[ArrayLike, "... d"]) -> Float[Array, "... d"]:
        """The unit normal grad f / |grad f| (outward: f grows outside)."""
        g = self.gradient(x)
        norm = jnp.linalg.norm(g, axis=-1, keepdims=True)
        return g / jnp.where(norm > 0, norm, 1.0)


class RBFModel(AbstractModel):
    """f(x) = sum_j w_j phi(|x' - c_j|) + p(x'), with x' = (x - shift) / scale (paper eq. 5).

    Centres, weights and polynomial coefficients live in the normalised frame (the unit box the fit
    was solved in); `shift` and `scale` map the user's coordinates into it, so the model is called
    with points in the user's own units. All arrays are leaves: the model can be differentiated,
    vmapped and jitted like any pytree.

    **Fields:**
    - `centres`: (m, d) centres, normalised.
    - `weights`: (m,) RBF weights.
    - `coeffs`: (k,) coefficients of [1, x'_1, ..., x'_d] (k = 0, 1 or d + 1).
    - `kernel`: the kernel, its radius in normalised units.
    - `shift`, `scale`: the normalising transform.
    - `residual`: max-norm relative residual of the solve that produced the model.
    - `degree`: polynomial degree (-1, 0 or 1), static.
    - `background`: None, or a model g added to f (`fit(..., background=g)` fits the values minus
      g): f(x) = sum_j w_j phi(|x' - c_j|) + p(x') + g(x). Far from the centres a decaying kernel
      leaves f = p + g, so a background with the right sign there keeps spurious pieces of
      surface away (`jaxrbf.surface_background`).
    """

    centres: Float[Array, "m d"]
    weights: Float[Array, " m"]
    coeffs: Float[Array, " k"]
    kernel: AbstractKernel
    shift: Float[Array, " d"]
    scale: Float[Array, ""]
    residual: Float[Array, ""]
    degree: int = eqx.field(static=True)
    background: AbstractModel | None = None

    def _background_normalised(self, xn):
        """The background's points in its own frame, and d(its frame)/d(this frame)."""
        bg = self.background
        return bg.normalise(xn * self.scale + self.shift), self.scale / bg.scale

    def _eval_normalised(self, xn: Float[Array, "b d"]) -> Float[Array, " b"]:
        phi = kernel_block(self.kernel, xn, self.centres)
        f = phi @ self.weights + poly_basis(xn, self.degree) @ self.coeffs
        if self.background is not None:
            f = f + self.background._eval_normalised(self._background_normalised(xn)[0])
        return f

    def _value_grad_normalised(self, xn):
        # grad f = 2 sum_j w_j phi'(r_j^2) (x - c_j) + grad p, with phi' the kernel's derivative
        # in r^2 from one elementwise forward-mode pass, and both sums in one product of the
        # (b, m) block with [w, w c] (about 4x the cost of the values alone, against 6-7x for
        # reverse mode, whose backward pass also keeps the block's intermediates).
        r2 = pairwise_sq(xn, self.centres)
        phi, dphi = jax.jvp(self.kernel.from_r2, (r2,), (jnp.ones_like(r2),))
        f = phi @ self.weights + poly_basis(xn, self.degree) @ self.coeffs
        wc = jnp.concatenate([self.weights[:, None], self.weights[:, None] * self.centres], 1)
        a = dphi @ wc
        g = 2.0 * (a[:, :1] * xn - a[:, 1:])
        if self.degree >= 1:
            g = g + self.coeffs[1:]
        if self.background is not None:
            xb, ratio = self._background_normalised(xn)
            fb, gb = self.background._value_grad_normalised(xb)
            f, g = f + fb, g + gb * ratio
        return f, g

    def _block_rows(self) -> int:
        return block_rows(self.centres.shape[0])

    def bounds(self) -> tuple[Array, Array]:
        """Bounding box (lo, hi) of the centres in the user's coordinates."""
        world = self.centres * self.scale + self.shift
        return world.min(axis=0), world.max(axis=0)


def _traced(*trees) -> bool:
    """Whether any array in `trees` is being traced (jit, vmap, grad): then evaluation stays
    inside the caller's computation instead of being split over devices on the host."""
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(trees))


# Compiled once per (model structure, number of points): repeated calls do not retrace.
@eqx.filter_jit
def _values(model: AbstractModel, flat: Array) -> Array:
    rows = model._block_rows()
    return map_blocks(lambda b: model._eval_normalised(model.normalise(b)), flat, rows)


@eqx.filter_jit
def _values_gradients(model: AbstractModel, flat: Array) -> Array:
    """(n, 1 + d): f, then grad f in the user's units."""
    rows = model._block_rows()

    def block(b):
        f, g = model._value_grad_normalised(model.normalise(b))
        return jnp.concatenate([f[:, None], g / model.scale], axis=1)

    return map_blocks(block, flat, rows)
