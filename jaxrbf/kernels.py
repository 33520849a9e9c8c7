"""Radial basis kernels as immutable equinox modules.

Every kernel is written as a function of the *squared* distance `r2`, so that no square root is
taken where none is needed, and the square roots that are needed are "safe": at r = 0 they return 0
with a zero gradient instead of NaN (the `safe_mask` pattern of jax-md). Values and gradients of
every kernel are finite at the centres.

Sign conventions and minimum polynomial degrees follow `scipy.interpolate.RBFInterpolator`
(Fasshauer, *Meshfree Approximation Methods with MATLAB*, ch. 8): with these signs every kernel is
conditionally positive definite of order `min_degree + 1`, so that the kernel matrix restricted to
the null space of the polynomial block is positive definite. That is what the `cholesky` solver uses.

| name                   | phi(r)                          | min_degree | positive definite |
|------------------------|---------------------------------|------------|-------------------|
| `linear`               | -r                              | 0          | no                |
| `cubic`                | r^3                             | 1          | no                |
| `thin-plate`           | r^2 log r                       | 1          | no                |
| `gaussian`             | exp(-(r/R)^2)                   | -1         | yes               |
| `multiquadric`         | -sqrt(1 + (r/R)^2)              | 0          | no                |
| `inverse-multiquadric` | 1/sqrt(1 + (r/R)^2)             | -1         | yes               |
| `wendland`             | (1 - r/R)_+^4 (4 r/R + 1)       | -1         | yes (d <= 3)      |

`R` is the kernel radius (for Wendland, the radius of support), a differentiable array leaf.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._errors import InputError

__all__ = [
    "AbstractKernel",
    "Cubic",
    "Gaussian",
    "InverseMultiquadric",
    "Linear",
    "Multiquadric",
    "ThinPlate",
    "Wendland",
    "KERNELS",
    "kernel_class",
    "make_kernel",
]


def _safe_sqrt(r2: Array) -> Array:
    """sqrt with a finite (zero) gradient at 0."""
    positive = r2 > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, r2, 1.0)), 0.0)


class AbstractKernel(eqx.Module):
    """A radial function phi, evaluated on squared distances.

    Subclasses define `name`, `min_degree` (the lowest polynomial degree that makes the
    interpolation problem well posed; -1 means no polynomial is needed), `positive_definite` and
    `has_radius`, and implement `from_r2`.
    """

    name: ClassVar[str]
    min_degree: ClassVar[int]
    positive_definite: ClassVar[bool]
    has_radius: ClassVar[bool] = False
    #: phi(s r) = s^k phi(r) up to a polynomial the fit absorbs (0 for kernels with a radius, which
    #: scales with the coordinates instead). Used to express `smoothing` in the input's units.
    homogeneity: ClassVar[int] = 0

    def from_r2(self, r2: Float[Array, "..."]) -> Float[Array, "..."]:
        raise NotImplementedError

    def __call__(self, r: Float[ArrayLike, "..."]) -> Float[Array, "..."]:
        """phi(r) for distances `r` (not squared)."""
        r = jnp.asarray(r)
        return self.from_r2(r * r)

    def scaled(self, factor: float) -> AbstractKernel:
        """The same kernel with its radius divided by `factor` (coordinates multiplied by it)."""
        return self


class Linear(AbstractKernel):
    homogeneity: ClassVar[int] = 1
    name: ClassVar[str] = "linear"
    min_degree: ClassVar[int] = 0
    positive_definite: ClassVar[bool] = False

    def from_r2(self, r2):
        return -_safe_sqrt(r2)


class Cubic(AbstractKernel):
    homogeneity: ClassVar[int] = 3
    name: ClassVar[str] = "cubic"
    min_degree: ClassVar[int] = 1
    positive_definite: ClassVar[bool] = False

    def from_r2(self, r2):
        return r2 * _safe_sqrt(r2)


class ThinPlate(AbstractKernel):
    homogeneity: ClassVar[int] = 2
    name: ClassVar[str] = "thin-plate"
    min_degree: ClassVar[int] = 1
    positive_definite: ClassVar[bool] = False

    def from_r2(self, r2):
        positive = r2 > 0
        return jnp.where(positive, 0.5 * r2 * jnp.log(jnp.where(positive, r2, 1.0)), 0.0)


class _RadiusKernel(AbstractKernel):
    """A kernel with a shape parameter: the radius `R` (a differentiable leaf)."""

    radius: Float[Array, ""]
    has_radius: ClassVar[bool] = True

    def __init__(self, radius: float | Array = 1.0):
        r = jnp.asarray(radius, dtype=float)
        if r.shape != ():
            raise InputError(f"`radius` must be a scalar, got shape {r.shape}")
        if not isinstance(r, jnp.ndarray) or not _is_traced(r):
            value = float(r)
            if not (value > 0 and jnp.isfinite(value)):
                raise InputError(
                    f"`radius` must be a positive finite number, got {value!r}; "
                    "it is the kernel's length scale in the input's units"
                )
        self.radius = r

    def scaled(self, factor):
        return type(self)(self.radius * factor)


def _is_traced(x) -> bool:
    import jax.core

    return isinstance(x, jax.core.Tracer)


class Gaussian(_RadiusKernel):
    name: ClassVar[str] = "gaussian"
    min_degree: ClassVar[int] = -1
    positive_definite: ClassVar[bool] = True

    def from_r2(self, r2):
        return jnp.exp(-r2 / self.radius**2)


class Multiquadric(_RadiusKernel):
    name: ClassVar[str] = "multiquadric"
    min_degree: ClassVar[int] = 0
    positive_definite: ClassVar[bool] = False

    def from_r2(self, r2):
        return -jnp.sqrt(1.0 + r2 / self.radius**2)


class InverseMultiquadric(_RadiusKernel):
    name: ClassVar[str] = "inverse-multiquadric"
    min_degree: ClassVar[int] = -1
    positive_definite: ClassVar[bool] = True

    def from_r2(self, r2):
        return 1.0 / jnp.sqrt(1.0 + r2 / self.radius**2)


class Wendland(_RadiusKernel):
    """Wendland's C2 function, compactly supported on r < radius (positive definite for d <= 3)."""

    name: ClassVar[str] = "wendland"
    min_degree: ClassVar[int] = -1
    positive_definite: ClassVar[bool] = True

    def from_r2(self, r2):
        t = _safe_sqrt(r2) / self.radius
        s = jnp.clip(1.0 - t, 0.0, None)
        return s**4 * (4.0 * t + 1.0)


KERNELS: dict[str, type[AbstractKernel]] = {
    k.name: k
    for k in (Linear, Cubic, ThinPlate, Gaussian, Multiquadric, InverseMultiquadric, Wendland)
}
_ALIASES = {
    "thin_plate_spline": "thin-plate",
    "thin-plate-spline": "thin-plate",
    "tps": "thin-plate",
    "inverse_multiquadric": "inverse-multiquadric",
    "imq": "inverse-multiquadric",
    "mq": "multiquadric",
}


def kernel_class(name: str) -> type[AbstractKernel]:
    """The kernel class for a name (scipy's spellings are accepted)."""
    if not isinstance(name, str):
        raise InputError(f"`kernel` must be a name or an AbstractKernel, got {type(name).__name__}")
    key = _ALIASES.get(name.lower(), name.lower())
    if key not in KERNELS:
        raise InputError(f"unknown kernel {name!r}; expected one of {', '.join(KERNELS)}")
    return KERNELS[key]


def make_kernel(
    kernel: str | AbstractKernel, radius: float | Array | None = None
) -> AbstractKernel:
    """A kernel from its name (scipy's spellings are accepted) or an instance.

    **Arguments:**
    - `kernel`: a name in `KERNELS` or an `AbstractKernel`.
    - `radius`: the length scale for kernels that have one; required for them, rejected otherwise.

    **Returns:** the kernel module.
    """
    if isinstance(kernel, AbstractKernel):
        if radius is not None:
            raise InputError(
                "`radius` was given together with a kernel instance; set it on the kernel"
            )
        return kernel
    cls = kernel_class(kernel)
    key = cls.name
    if cls.has_radius:
        if radius is None:
            raise InputError(
                f"the {key} kernel needs a `radius` (its length scale in the input's units)"
            )
        return cls(radius)
    if radius is not None:
        raise InputError(f"the {key} kernel has no radius; leave `radius` unset")
    return cls()
