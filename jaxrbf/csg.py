"""Analytic primitives and constructive solid geometry (CSG) of implicits.

Every shape here is an implicit like a fitted model: an immutable `equinox.Module` (its numbers
are array leaves, so shapes can be jitted, vmapped and differentiated with respect to their
parameters), called on points of shape (..., d) to give values of shape (...), negative inside
and positive outside, with `gradient`, `normal` and `bounds` (the box `polygonize` and `render`
use by default). The children of a CSG node may be any implicit: primitives, other CSG nodes, an
`RBFModel` or a `PartitionModel` (`model - Sphere(...)` carves a ball out of a reconstruction).

The primitives are exact signed distances (|grad f| = 1). Union, intersection and difference are
the min/max of Ricci (1973), whose result is a distance bound outside the blend; the smooth
variants (`radius > 0`) replace min(a, b) with the polynomial smooth minimum
min(a, b) - r h^2 / 4, h = max(r - |a - b|, 0) / r, which differs from the min only where the two
values are within `radius` of each other and rounds the crease over that width. All values and
gradients are computed in float64 (the dtype of the shape's parameters).

Operators: `a | b` (union), `a & b` (intersection), `a - b` (difference), `-a` (complement).
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._errors import InputError

__all__ = [
    "AbstractShape",
    "Sphere",
    "Box",
    "Torus",
    "Cylinder",
    "Plane",
    "Union",
    "Intersection",
    "Difference",
    "Complement",
    "Offset",
    "Affine",
    "translate",
    "rotate",
    "scale",
]


def _array(name: str, v, shape=None) -> Array:
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"`{name}` must be numeric, got {v!r}") from None
    if shape is not None and a.shape != shape:
        raise InputError(f"`{name}` must have shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"`{name}` must be finite, got {a.tolist()}")
    return jnp.asarray(a)


def _positive(name: str, v) -> Array:
    a = _array(name, v, ())
    if not float(a) > 0:
        raise InputError(f"`{name}` must be positive, got {float(a)}")
    return a


def _point(name: str, v) -> Array:
    a = _array(name, v)
    if a.ndim != 1 or a.shape[0] < 1:
        raise InputError(f"`{name}` must be a point (d coordinates), got shape {a.shape}")
    return a


def _safe_norm(v: Array) -> Array:
    """|v| along the last axis with a finite (zero) gradient at v = 0."""
    sq = jnp.sum(v * v, axis=-1)
    ok = sq > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, sq, 1.0)), 0.0)


def _dim_of(shape) -> int | None:
    return getattr(shape, "dim", None)


def _bounds_of(shape, dim: int) -> tuple[np.ndarray, np.ndarray]:
    """A child's bounding box, or all of space when it does not know one."""
    if hasattr(shape, "bounds"):
        lo, hi = shape.bounds()
        return np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    return np.full(dim, -np.inf), np.full(dim, np.inf)


def _smin(a: Array, b: Array, r: Array | None) -> Array:
    if r is None:
        return jnp.minimum(a, b)
    h = jnp.maximum(r - jnp.abs(a - b), 0.0) / r
    return jnp.minimum(a, b) - 0.25 * r * h * h


def _smax(a: Array, b: Array, r: Array | None) -> Array:
    return -_smin(-a, -b, r)


class AbstractShape(eqx.Module):
    """Base class of the primitives and CSG nodes: evaluation on (..., d) points, gradients from
    `jax.grad`, bounds and the CSG operators. Subclasses implement `_eval` on (n, d) points,
    `dim` and `bounds`."""

    def _eval(self, x: Float[Array, "n d"]) -> Float[Array, " n"]:
        raise NotImplementedError

    @property
    def dim(self) -> int:
        raise NotImplementedError

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounding box `(lo, hi)` of the region where f <= 0 (infinite along unbounded axes)."""
        raise NotImplementedError

    def _flat(self, x: ArrayLike) -> tuple[Array, tuple[int, ...]]:
        x = jnp.asarray(x)
        if x.ndim < 1 or x.shape[-1] != self.dim:
            raise InputError(
                f"points must have shape (..., {self.dim}) for this {self.dim}-D shape, got {x.shape}"
            )
        if not jnp.issubdtype(x.dtype, jnp.floating):
            x = x.astype(float)
        return x.reshape(-1, self.dim), x.shape[:-1]

    def __call__(self, x: Float[ArrayLike, "... d"]) -> Float[Array, "..."]:
        """f at points `x` of shape (..., d); returns shape (...)."""
        flat, lead = self._flat(x)
        return self._eval(flat).reshape(lead)

    def gradient(self, x: Float[ArrayLike, "... d"]) -> Float[Array, "... d"]:
        """grad f at `x`, from `jax.grad`; shape (..., d)."""
        flat, lead = self._flat(x)
        g = jax.grad(lambda y: jnp.sum(self._eval(y)))(flat)
        return g.reshape(lead + (self.dim,))

    def normal(self, x: Float[ArrayLike, "... d"]) -> Float[Array, "... d"]:
        """The unit normal grad f / |grad f| (outward)."""
        g = self.gradient(x)
        n = jnp.linalg.norm(g, axis=-1, keepdims=True)
        return g / jnp.where(n > 0, n, 1.0)

    def __or__(self, other) -> Union:
        return Union(self, other)

    def __ror__(self, other) -> Union:
        return Union(other, self)

    def __and__(self, other) -> Intersection:
        return Intersection(self, other)

    def __rand__(self, other) -> Intersection:
        return Intersection(other, self)

    def __sub__(self, other) -> Difference:
        return Difference(self, other)

    def __rsub__(self, other) -> Difference:
        return Difference(other, self)

    def __neg__(self) -> Complement:
        return Complement(self)


# ---------------------------------------------------------------------------------- primitives


class Sphere(AbstractShape):
    """The ball |x - centre| <= radius in any dimension (a disc in 2-D): f = |x - c| - r."""

    centre: Float[Array, " d"]
    radius: Float[Array, ""]

    def __init__(self, centre=(0.0, 0.0, 0.0), radius=1.0):
        self.centre = _point("centre", centre)
        self.radius = _positive("radius", radius)

    @property
    def dim(self) -> int:
        return self.centre.shape[0]

    def _eval(self, x):
        return _safe_norm(x - self.centre) - self.radius

    def bounds(self):
        c, r = np.asarray(self.centre), float(self.radius)
        return c - r, c + r


class Box(AbstractShape):
    """The axis-aligned box |x_k - centre_k| <= half_size_k in any dimension, with the exact
    signed distance |max(q, 0)| + min(max_k q_k, 0), q = |x - c| - half_size (Quilez)."""

    centre: Float[Array, " d"]
    half_size: Float[Array, " d"]

    def __init__(self, centre=(0.0, 0.0, 0.0), half_size=(1.0, 1.0, 1.0)):
        self.centre = _point("centre", centre)
        hs = _array("half_size", np.broadcast_to(np.asarray(half_size, float), self.centre.shape))
        if not np.all(np.asarray(hs) > 0):
            raise InputError(
                f"`half_size` must be positive on every axis, got {np.asarray(hs).tolist()}"
            )
        self.half_size = hs

    @property
    def dim(self) -> int:
        return self.centre.shape[0]

    def _eval(self, x):
        q = jnp.abs(x - self.centre) - self.half_size
        return _safe_norm(jnp.maximum(q, 0.0)) + jnp.minimum(jnp.max(q, axis=-1), 0.0)

    def bounds(self):
        c, h = np.asarray(self.centre), np.asarray(self.half_size)
        return c - h, c + h


class Torus(AbstractShape):
    """A torus around the z axis through `centre`: the circle of radius `major` in the plane
    z = centre_z, thickened by `minor`. f = |(|x_xy - c_xy| - major, x_z - c_z)| - minor
    (rotate it with `rotate` for another axis)."""

    centre: Float[Array, " 3"]
    major: Float[Array, ""]
    minor: Float[Array, ""]

    def __init__(self, centre=(0.0, 0.0, 0.0), major=1.0, minor=0.25):
        self.centre = _array("centre", centre, (3,))
        self.major = _positive("major", major)
        self.minor = _positive("minor", minor)

    @property
    def dim(self) -> int:
        return 3

    def _eval(self, x):
        p = x - self.centre
        q = jnp.stack([_safe_norm(p[:, :2]) - self.major, p[:, 2]], axis=-1)
        return _safe_norm(q) - self.minor

    def bounds(self):
        c = np.asarray(self.centre)
        big, small = float(self.major), float(self.minor)
        e = np.array([big + small, big + small, small])
        return c - e, c + e


class Cylinder(AbstractShape):
    """A solid cylinder along the z axis through `centre`, of `radius`, capped at
    z = centre_z +/- `half_height` (exact signed distance), or infinite when `half_height` is
    None (f = |x_xy - c_xy| - radius; give `bounds` to draw it, or intersect it)."""

    centre: Float[Array, " 3"]
    radius: Float[Array, ""]
    half_height: Float[Array, ""] | None

    def __init__(self, centre=(0.0, 0.0, 0.0), radius=0.5, half_height=1.0):
        self.centre = _array("centre", centre, (3,))
        self.radius = _positive("radius", radius)
        self.half_height = None if half_height is None else _positive("half_height", half_height)

    @property
    def dim(self) -> int:
        return 3

    def _eval(self, x):
        p = x - self.centre
        radial = _safe_norm(p[:, :2]) - self.radius
        if self.half_height is None:
            return radial
        q = jnp.stack([radial, jnp.abs(p[:, 2]) - self.half_height], axis=-1)
        return _safe_norm(jnp.maximum(q, 0.0)) + jnp.minimum(jnp.max(q, axis=-1), 0.0)

    def bounds(self):
        c, r = np.asarray(self.centre), float(self.radius)
        hh = np.inf if self.half_height is None else float(self.half_height)
        e = np.array([r, r, hh])
        return c - e, c + e


class Plane(AbstractShape):
    """The half-space n . x <= offset (n normalised), f = n . x - offset: positive on the side
    the normal points to. Unbounded: intersect it with a bounded shape, or give `bounds`."""

    unit_normal: Float[Array, " d"]
    offset: Float[Array, ""]

    def __init__(self, normal=(0.0, 0.0, 1.0), offset=0.0):
        n = _point("normal", normal)
        length = float(jnp.linalg.norm(n))
        if length == 0:
            raise InputError("`normal` of a plane must be a non-zero vector")
        self.unit_normal = n / length
        self.offset = _array("offset", offset, ())

    @property
    def dim(self) -> int:
        return self.unit_normal.shape[0]

    def _eval(self, x):
        return x @ self.unit_normal - self.offset

    def bounds(self):
        n = np.asarray(self.unit_normal)
        lo, hi = np.full(self.dim, -np.inf), np.full(self.dim, np.inf)
        # A half-space is bounded along an axis only when the normal is that axis.
        k = int(np.argmax(np.abs(n)))
        if np.isclose(abs(n[k]), 1.0):
            if n[k] > 0:
                hi[k] = float(self.offset)
            else:
                lo[k] = -float(self.offset)
        return lo, hi


# ----------------------------------------------------------------------------------------- CSG


def _children(shapes) -> tuple:
    if len(shapes) < 2:
        raise InputError(f"CSG needs at least two shapes, got {len(shapes)}")
    for s in shapes:
        if not callable(s):
            raise InputError(f"CSG children must be implicits (callables), got {type(s).__name__}")
    dims = {d for d in map(_dim_of, shapes) if d is not None}
    if len(dims) > 1:
        raise InputError(f"CSG children must have the same dimension, got {sorted(dims)}")
    return tuple(shapes)


def _radius(radius) -> Array | None:
    if radius is None or float(radius) == 0:
        return None
    return _positive("radius", radius)


def _common_dim(shapes) -> int:
    for s in shapes:
        d = _dim_of(s)
        if d is not None:
            return d
    raise InputError("cannot tell the dimension of these shapes: none has a `dim`")


def _values(shapes, x) -> list[Array]:
    return [s._eval(x) if isinstance(s, AbstractShape) else s(x) for s in shapes]


class _Fold(AbstractShape):
    """The children folded pairwise with `_pair` (min or max, or their smooth variants)."""

    shapes: tuple
    radius: Float[Array, ""] | None

    def __init__(self, *shapes: Callable, radius: float = 0.0):
        self.shapes = _children(shapes)
        self.radius = _radius(radius)

    @property
    def dim(self) -> int:
        return _common_dim(self.shapes)

    def _pair(self, a: Array, b: Array) -> Array:
        raise NotImplementedError

    def _eval(self, x):
        vals = _values(self.shapes, x)
        out = vals[0]
        for v in vals[1:]:
            out = self._pair(out, v)
        return out


class Union(_Fold):
    """min of the children (the solid of any), or their smooth minimum with blending `radius`."""

    def _pair(self, a, b):
        return _smin(a, b, self.radius)

    def bounds(self):
        boxes = [_bounds_of(s, self.dim) for s in self.shapes]
        pad = 0.0 if self.radius is None else float(self.radius) / 4
        return np.min([b[0] for b in boxes], 0) - pad, np.max([b[1] for b in boxes], 0) + pad


class Intersection(_Fold):
    """max of the children (the solid common to all), or their smooth maximum."""

    def _pair(self, a, b):
        return _smax(a, b, self.radius)

    def bounds(self):
        boxes = [_bounds_of(s, self.dim) for s in self.shapes]
        return np.max([b[0] for b in boxes], 0), np.min([b[1] for b in boxes], 0)


class Difference(AbstractShape):
    """max(a, -b): the solid of `a` with `b` removed (smoothly over `radius` if given)."""

    shapes: tuple
    radius: Float[Array, ""] | None

    def __init__(self, a: Callable, b: Callable, radius: float = 0.0):
        self.shapes = _children((a, b))
        self.radius = _radius(radius)

    @property
    def dim(self) -> int:
        return _common_dim(self.shapes)

    def _eval(self, x):
        a, b = _values(self.shapes, x)
        return _smax(a, -b, self.radius)

    def bounds(self):
        return _bounds_of(self.shapes[0], self.dim)


class Complement(AbstractShape):
    """-f: inside and outside swapped (unbounded)."""

    shape: Callable

    def __init__(self, shape: Callable):
        if not callable(shape):
            raise InputError(f"`shape` must be an implicit, got {type(shape).__name__}")
        self.shape = shape

    @property
    def dim(self) -> int:
        return _common_dim((self.shape,))

    def _eval(self, x):
        return -_values((self.shape,), x)[0]

    def bounds(self):
        return np.full(self.dim, -np.inf), np.full(self.dim, np.inf)


class Offset(AbstractShape):
    """f - distance: the surface moved outwards by `distance` (inwards if negative); exact for a
    signed distance, a first-order move of |grad f| * distance otherwise."""

    shape: Callable
    distance: Float[Array, ""]

    def __init__(self, shape: Callable, distance: float):
        if not callable(shape):
            raise InputError(f"`shape` must be an implicit, got {type(shape).__name__}")
        self.shape = shape
        self.distance = _array("distance", distance, ())

    @property
    def dim(self) -> int:
        return _common_dim((self.shape,))

    def _eval(self, x):
        return _values((self.shape,), x)[0] - self.distance

    def bounds(self):
        lo, hi = _bounds_of(self.shape, self.dim)
        d = max(float(self.distance), 0.0)
        return lo - d, hi + d


class Affine(AbstractShape):
    """The shape moved by the affine map y = A x + b: f'(y) = s f(A^-1 (y - b)), with s the
    smallest singular value of A, so that a signed distance stays exact under rotations and
    uniform scalings and stays a lower bound of the distance under any other map."""

    shape: Callable
    inverse: Float[Array, "d d"]
    offset: Float[Array, " d"]
    factor: Float[Array, ""]
    matrix: Float[Array, "d d"]

    def __init__(self, shape: Callable, matrix, offset=None):
        if not callable(shape):
            raise InputError(f"`shape` must be an implicit, got {type(shape).__name__}")
        d = _common_dim((shape,))
        a = np.asarray(_array("matrix", matrix, (d, d)))
        sv = np.linalg.svd(a, compute_uv=False)
        if sv.min() <= 1e-12 * max(sv.max(), 1e-300):
            raise InputError(f"`matrix` must be invertible, got singular values {sv.tolist()}")
        self.shape = shape
        self.matrix = jnp.asarray(a)
        self.inverse = jnp.asarray(np.linalg.inv(a))
        self.offset = _array("offset", np.zeros(d) if offset is None else offset, (d,))
        self.factor = jnp.asarray(sv.min())

    @property
    def dim(self) -> int:
        return self.offset.shape[0]

    def _eval(self, x):
        return self.factor * _values((self.shape,), (x - self.offset) @ self.inverse.T)[0]

    def bounds(self):
        lo, hi = _bounds_of(self.shape, self.dim)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            return np.full(self.dim, -np.inf), np.full(self.dim, np.inf)
        corners = (
            np.array(np.meshgrid(*zip(lo, hi, strict=True), indexing="ij")).reshape(self.dim, -1).T
        )
        moved = corners @ np.asarray(self.matrix).T + np.asarray(self.offset)
        return moved.min(axis=0), moved.max(axis=0)


def translate(shape: Callable, offset) -> Affine:
    """The shape moved by `offset`."""
    d = _common_dim((shape,))
    return Affine(shape, np.eye(d), offset)


def scale(shape: Callable, factor, centre=None) -> Affine:
    """The shape scaled by `factor` (a number, or one per axis) about `centre` (default the
    origin)."""
    d = _common_dim((shape,))
    f = np.broadcast_to(np.asarray(factor, dtype=float), (d,))
    c = np.zeros(d) if centre is None else np.asarray(_array("centre", centre, (d,)))
    return Affine(shape, np.diag(f), c - f * c)


def rotate(shape: Callable, axis, degrees: float, centre=None) -> Affine:
    """The 3-D shape rotated by `degrees` about `axis` (right-hand rule) through `centre`
    (default the origin); in 2-D, `axis` is ignored (pass None) and the rotation is
    anticlockwise."""
    d = _common_dim((shape,))
    a = np.radians(float(degrees))
    if d == 2:
        r = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    elif d == 3:
        k = np.asarray(_array("axis", axis, (3,)))
        n = np.linalg.norm(k)
        if n == 0:
            raise InputError("rotation `axis` must be a non-zero vector")
        k = k / n
        kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        r = np.eye(3) + np.sin(a) * kx + (1 - np.cos(a)) * kx @ kx
    else:
        raise InputError(f"rotate works in 2-D and 3-D, got a {d}-D shape")
    c = np.zeros(d) if centre is None else np.asarray(_array("centre", centre, (d,)))
    return Affine(shape, r, c - r @ c)
