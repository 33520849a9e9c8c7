"""Pictures of 3-D implicits: a look-at camera, ray marching, root refinement, shading and PNG.

The work runs in three jit-compiled kernels, each on fixed-size chunks of rays (the last chunk
padded), so an image of any size compiles each kernel once per implicit:

1. **Marching** (`_march`). Before any ray is cast, f and its analytic gradient are sampled on a
   coarse grid over the bounding box (`grid` cells along the longest side). A cell may hold the
   surface when its corners disagree in sign or when the first-order distance estimate
   |f| / |grad f| at a corner is below `band` cell diagonals; those cells, grown by one cell, are
   the *band*, and every other cell stores its chessboard distance (in cells) to the band. A ray
   first leaves the picture if it misses the bounding box (slab test, on the host); inside the box
   it jumps over empty space cube by cube with that distance (no evaluation of f), and inside the
   band it steps by `safety * |f| / G`, where G is the largest |grad f| found on the grid around
   the cell (RBF fields are not exact distances, hence the bound from the gradient and the safety
   factor), at most one cell and at least a quarter of a pixel's footprint. The first sign change
   of f brackets the hit. Rays are marched `_ROUND` steps at a time and the survivors are packed
   into fresh chunks after every round (a wavefront), so that a few slow grazing rays do not keep
   whole chunks busy.
2. **Refinement** (`_refine`): bisection of the bracket, then safeguarded Newton steps along the
   ray with the directional derivative from `jax.jvp`; then the normal from the analytic gradient
   (`value_and_gradient` of RBF models; forward-mode JAX for other callables).
3. **Shading** (`_shade`): Lambert plus Blinn-Phong for one or two directional lights fixed to the
   camera, optional shadow rays (marched like primary rays) and ambient occlusion, optional
   colouring by a scalar (mean curvature, or any function of the hit points such as the signed
   error against a reference mesh), over a background.

Precision: everything runs in float64 (JAX's 64-bit mode, on in jaxrbf). RBF models evaluate in
float64 whatever the caller does (their weights cancel strongly), so marching in float32 would
save nothing on the evaluations that dominate the time, and the hit depths keep float64 accuracy.

Works on any implicit: an `RBFModel`, a `PartitionModel`, the primitives and CSG combinations of
`jaxrbf.csg`, or any JAX-traceable callable mapping (n, 3) points to (n,) values (with
`bounds=(lo, hi)` when it has no `bounds()` method).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._constraints import progress_bar
from ._errors import InputError
from ._project import value_and_gradient as _value_grad
from ._util import check_memory

__all__ = ["Camera", "Rendering", "render", "save_png", "mesh_error", "mean_curvature"]

_CHUNK = 4096  # rays per compiled chunk
_ROUND = 4  # marching steps per chunk between two wavefront compactions
_ACTIVE, _BRACKET, _MISS = 0, 1, 2
_IMAGE_EXTS = (".png",)
_MAX_PIXELS = 8192 * 8192
#: Host bytes per pixel of a frame, an upper estimate (colour, depth, normals, masks, float64).
RENDER_PIXEL_BYTES = 128


# ------------------------------------------------------------------------------------- camera


def _vec(name: str, v, dim: int = 3) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"camera `{name}` must be {dim} numbers, got {v!r}") from None
    if a.shape != (dim,):
        raise InputError(f"camera `{name}` must be {dim} numbers, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"camera `{name}` must be finite, got {a.tolist()}")
    return a


_AXES = {
    "x": (1.0, 0.0, 0.0),
    "y": (0.0, 1.0, 0.0),
    "z": (0.0, 0.0, 1.0),
    "-x": (-1.0, 0.0, 0.0),
    "-y": (0.0, -1.0, 0.0),
    "-z": (0.0, 0.0, -1.0),
}


def _up_vector(up) -> np.ndarray:
    if isinstance(up, str):
        if up not in _AXES:
            raise InputError(f"unknown up axis {up!r}; expected one of {', '.join(_AXES)}")
        return np.array(_AXES[up])
    u = _vec("up", up)
    n = np.linalg.norm(u)
    if n == 0:
        raise InputError("camera `up` must be a non-zero vector")
    return u / n


@dataclass(frozen=True)
class Camera:
    """A pinhole camera looking from `position` at `target`.

    **Fields:**
    - `position`, `target`: 3-D points (distinct, finite).
    - `up`: the direction that appears upwards in the picture (not parallel to the view); a vector
      or one of `"x"`, `"y"`, `"z"`, `"-x"`, `"-y"`, `"-z"`.
    - `fov`: vertical field of view in degrees, in (0, 180).
    - `size`: `(width, height)` of the image in pixels.

    Pixel (i, j) (row i from the top, column j from the left) looks through its centre.
    `Camera.orbit` frames a bounding box from an azimuth and an elevation.
    """

    position: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] | str = (0.0, 1.0, 0.0)
    fov: float = 35.0
    size: tuple[int, int] = (512, 512)

    def __post_init__(self):
        pos, tgt = _vec("position", self.position), _vec("target", self.target)
        up = _up_vector(self.up)
        try:
            fov = float(self.fov)
        except (TypeError, ValueError):
            raise InputError(
                f"camera `fov` must be a number of degrees, got {self.fov!r}"
            ) from None
        if not (np.isfinite(fov) and 0 < fov < 180):
            raise InputError(f"camera `fov` must be in (0, 180) degrees, got {self.fov}")
        size = _check_size(self.size)
        view = tgt - pos
        dist = np.linalg.norm(view)
        if not dist > 1e-12 * max(1.0, np.abs(pos).max()):
            raise InputError(
                f"camera `target` equals `position` ({pos.tolist()}): the camera needs a direction"
            )
        if np.linalg.norm(np.cross(view / dist, up)) < 1e-6:
            raise InputError(
                "camera `up` is parallel to the viewing direction: choose another up vector"
            )
        object.__setattr__(self, "position", tuple(pos.tolist()))
        object.__setattr__(self, "target", tuple(tgt.tolist()))
        object.__setattr__(self, "up", tuple(up.tolist()))
        object.__setattr__(self, "fov", fov)
        object.__setattr__(self, "size", size)

    @property
    def width(self) -> int:
        return self.size[0]

    @property
    def height(self) -> int:
        return self.size[1]

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`(forward, right, up)`: orthonormal, right-handed (right = forward x up)."""
        f = np.subtract(self.target, self.position)
        f = f / np.linalg.norm(f)
        r = np.cross(f, self.up)
        r = r / np.linalg.norm(r)
        return f, r, np.cross(r, f)

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """`(origins, directions)`, each (height * width, 3) float64, row-major from the top-left
        pixel; directions have unit length."""
        w, h = self.size
        f, r, u = self.basis()
        tan = np.tan(np.radians(self.fov) / 2)
        x = (2 * (np.arange(w) + 0.5) / w - 1) * tan * w / h
        y = (1 - 2 * (np.arange(h) + 0.5) / h) * tan
        d = f + x[None, :, None] * r + y[:, None, None] * u
        d = (d / np.linalg.norm(d, axis=-1, keepdims=True)).reshape(-1, 3)
        return np.broadcast_to(np.asarray(self.position), d.shape).copy(), d

    def project(self, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Image coordinates of 3-D points: `(rows, cols, depth)`, with pixel (i, j)'s centre at
        (i, j) and depth the distance along the viewing direction (negative behind the camera)."""
        p = np.asarray(points, dtype=float) - np.asarray(self.position)
        f, r, u = self.basis()
        w, h = self.size
        tan = np.tan(np.radians(self.fov) / 2)
        z = p @ f
        with np.errstate(divide="ignore", invalid="ignore"):
            x = (p @ r) / (z * tan * w / h)
            y = (p @ u) / (z * tan)
        return (1 - y) / 2 * h - 0.5, (x + 1) / 2 * w - 0.5, z

    @classmethod
    def orbit(
        cls,
        bounds,
        azimuth: float = 30.0,
        elevation: float = 20.0,
        *,
        up="y",
        fov: float = 35.0,
        size=(512, 512),
        distance: float | None = None,
        margin: float = 1.05,
    ) -> Camera:
        """A camera on a sphere around a box, aimed at its centre, far enough that the box's
        bounding sphere (grown by `margin`) fills the narrower field of view.

        **Arguments:**
        - `bounds`: `(lo, hi)`, or an implicit with a `bounds()` method (a model, a CSG shape).
        - `azimuth`: degrees about `up`; 0 looks from the front (+z for a y-up scene, -y for a
          z-up scene), 90 from the right (+x).
        - `elevation`: degrees above the horizontal plane, in (-90, 90).
        - `up`, `fov`, `size`: as for `Camera`. `distance`: from the centre (default: framed).
        """
        lo, hi = _box(bounds)
        try:
            ok = np.isfinite(float(fov)) and 0 < float(fov) < 180
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise InputError(f"camera `fov` must be in (0, 180) degrees, got {fov!r}")
        for name, v in (("azimuth", azimuth), ("elevation", elevation)):
            if not np.isfinite(float(v)):
                raise InputError(f"`{name}` must be a finite angle in degrees, got {v}")
        if not -90 < float(elevation) < 90:
            raise InputError(f"`elevation` must be in (-90, 90) degrees, got {elevation}")
        u = _up_vector(up)
        front = np.array([0.0, 0.0, 1.0]) if abs(u[2]) < 0.9 else np.array([0.0, -1.0, 0.0])
        front = front - (front @ u) * u
        front /= np.linalg.norm(front)
        right = np.cross(u, front)
        az, el = np.radians(float(azimuth)), np.radians(float(elevation))
        direction = np.cos(el) * (np.cos(az) * front + np.sin(az) * right) + np.sin(el) * u
        centre = (lo + hi) / 2
        w, h = _check_size(size)
        half = np.radians(float(fov)) / 2 if np.isfinite(float(fov)) else np.nan
        narrow = min(half, np.arctan(np.tan(half) * w / h))
        if distance is None:
            radius = margin * np.linalg.norm(hi - lo) / 2
            distance = radius / np.sin(narrow) if 0 < narrow < np.pi / 2 else np.nan
        return cls(
            tuple(centre + float(distance) * direction), tuple(centre), tuple(u), fov, (w, h)
        )


def _check_size(size) -> tuple[int, int]:
    try:
        w, h = (int(s) for s in size)
        ok = all(float(s) == int(s) for s in size)
    except (TypeError, ValueError, OverflowError):
        raise InputError(
            f"image `size` must be two integers (width, height), got {size!r}"
        ) from None
    if not ok or w < 1 or h < 1:
        raise InputError(
            f"image `size` must be two positive integers (width, height), got {size!r}"
        )
    if w * h > _MAX_PIXELS:
        raise InputError(f"image `size` {w}x{h} is too large (at most {_MAX_PIXELS:,} pixels)")
    check_memory(RENDER_PIXEL_BYTES * w * h, f"an image of {w}x{h} pixels", "use a smaller `size`")
    return w, h


def _box(bounds) -> tuple[np.ndarray, np.ndarray]:
    if hasattr(bounds, "bounds") and callable(bounds.bounds):
        bounds = bounds.bounds()
    try:
        lo, hi = (np.asarray(b, dtype=float).reshape(-1) for b in bounds)
    except (TypeError, ValueError):
        raise InputError("`bounds` must be a pair (lo, hi) of 3-D points") from None
    if lo.shape != (3,) or hi.shape != (3,):
        raise InputError(f"`bounds` must be two 3-D points, got shapes {lo.shape} and {hi.shape}")
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi >= lo)):
        raise InputError(
            f"`bounds` must be finite with hi >= lo (got lo={lo}, hi={hi}); an unbounded implicit "
            "(a plane, an infinite cylinder) needs bounds=(lo, hi)"
        )
    return lo, hi


# -------------------------------------------------------------------------- acceleration grid


class _Grid(eqx.Module):
    """The coarse grid that guides the marching (arrays only: a pytree passed to the kernels)."""

    lo: jax.Array  # (3,) corner of the grid
    h: jax.Array  # () cell size
    skip: jax.Array  # (nx, ny, nz) int32: 0 in the band, else chessboard distance to it (cells)
    lipschitz: jax.Array  # (nx, ny, nz) largest |grad f| sampled around the cell


_values_gradients = eqx.filter_jit(_value_grad)  # f and grad f (see `jaxrbf._project`)


def _in_chunks(fn, arrays: Sequence[np.ndarray], n: int, chunk: int = _CHUNK, bar=None):
    """Call `fn` on fixed-size chunks of the rows of `arrays` (the last one padded with copies of
    row 0) and join the outputs (tuples of arrays) on the host."""
    outs = None
    for start in range(0, n, chunk):
        end = min(start + chunk, n)
        part = []
        for a in arrays:
            block = a[start:end]
            if end - start < chunk:
                block = np.concatenate(
                    [block, np.broadcast_to(a[:1], (chunk - (end - start),) + a.shape[1:])]
                )
            part.append(jnp.asarray(block))
        res = fn(*part)
        res = res if isinstance(res, tuple) else (res,)
        res = [np.asarray(r)[: end - start] for r in res]
        if outs is None:
            outs = [[] for _ in res]
        for o, r in zip(outs, res, strict=True):
            o.append(r)
        if bar is not None:
            bar.update(1)
    return tuple(np.concatenate(o) for o in outs)


def _build_grid(implicit, lo, hi, cells: int, band: float, bar) -> tuple[_Grid, np.ndarray]:
    from scipy.ndimage import distance_transform_cdt, maximum_filter

    h = float((hi - lo).max()) / cells
    n = np.maximum(np.ceil((hi - lo) / h).astype(int), 1)
    axes = [lo[k] + h * np.arange(n[k] + 1) for k in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    f, g = _in_chunks(lambda p: _values_gradients(implicit, p), [pts], len(pts), bar=bar)
    if not (np.all(np.isfinite(f)) and np.all(np.isfinite(g))):
        bad = int((~np.isfinite(f)).sum() + (~np.all(np.isfinite(g), axis=1)).sum())
        raise InputError(
            f"the implicit returned NaN or infinite values or gradients at {bad} of {len(pts)} "
            "grid points inside the bounds"
        )
    shape = tuple(n + 1)
    f = f.reshape(shape)
    gn = np.linalg.norm(g, axis=1).reshape(shape)
    corners = [
        (slice(a, a + n[0]), slice(b, b + n[1]), slice(c, c + n[2]))
        for a in (0, 1)
        for b in (0, 1)
        for c in (0, 1)
    ]
    fmin = np.min([f[c] for c in corners], axis=0)
    fmax = np.max([f[c] for c in corners], axis=0)
    gmax = np.max([gn[c] for c in corners], axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        dist = np.min([np.abs(f[c]) / gn[c] for c in corners], axis=0)
    band_cells = (fmin <= 0) & (fmax >= 0) | (dist < band * h * np.sqrt(3))
    band_cells = maximum_filter(band_cells, size=3, mode="constant")
    skip = distance_transform_cdt(~band_cells, metric="chessboard").astype(np.int32)
    if not band_cells.any():
        skip = np.full(tuple(n), 10 * cells, np.int32)
    lip = maximum_filter(gmax, size=3, mode="nearest")
    lip = np.where(lip > 0, lip, np.max(gmax) if np.max(gmax) > 0 else 1.0)
    grid = _Grid(jnp.asarray(lo), jnp.asarray(h), jnp.asarray(skip), jnp.asarray(lip))
    return grid, band_cells


# ------------------------------------------------------------------------------------ kernels


def _cell(grid: _Grid, p):
    shape = jnp.array(grid.skip.shape)
    idx = jnp.floor((p - grid.lo) / grid.h).astype(jnp.int32)
    return jnp.clip(idx, 0, shape - 1)


def _slab_exit(o, d, lo, hi):
    """Largest t at which the ray o + t d is still inside the box [lo, hi] (per ray)."""
    safe = jnp.where(d == 0, 1.0, d)
    t = jnp.where(d > 0, (hi - o) / safe, jnp.where(d < 0, (lo - o) / safe, jnp.inf))
    return jnp.min(t, axis=1)


def _skip_empty(grid: _Grid, o, d, t, t_far, live):
    """Advance each live ray over the empty cubes of the grid until it reaches the band (or
    leaves the box): from a cell at chessboard distance k from the band, every cell within k - 1
    cells is empty, so the ray may jump to where it leaves that cube."""
    eps = 1e-6 * grid.h

    def needs(t):
        k = grid.skip[tuple(_cell(grid, o + t[:, None] * d).T)]
        return live & (t < t_far) & (k > 0), k

    def cond(state):
        t, it = state
        return jnp.any(needs(t)[0]) & (it < 4 * sum(grid.skip.shape))

    def body(state):
        t, it = state
        need, k = needs(t)
        idx = _cell(grid, o + t[:, None] * d)
        lo = grid.lo + (idx - (k[:, None] - 1)) * grid.h
        hi = grid.lo + (idx + k[:, None]) * grid.h
        exit_ = _slab_exit(o, d, lo, hi)
        return jnp.where(need, jnp.maximum(exit_, t) + eps, t), it + 1

    t, _ = jax.lax.while_loop(cond, body, (t, jnp.asarray(0)))
    return t


@eqx.filter_jit
def _march(
    implicit, grid: _Grid, o, d, t, t_far, t_prev, f_prev, f_now, status, footprint, safety, steps
):
    """`steps` marching steps for a chunk of rays (see the module's docstring). A ray's `status`
    goes from active to bracketed ([t_prev, t] holds a sign change of f: f_prev, f_now) or missed.

    The step is the larger of the safe step `safety * |f| / G` and, while |f| decreases along the
    ray, 1.05 times the secant's prediction of the root (at most one cell): along a stretch where
    f is convex in t (approaching a surface, or passing a thin part) the secant line stays below
    f, so the first root cannot come before the predicted one, and the 5% overshoot brackets it
    in one step instead of the many small steps of sphere tracing."""

    def body(_, state):
        t, t_prev, f_prev, f_now, status = state
        live = status == _ACTIVE
        t = _skip_empty(grid, o, d, t, t_far, live)
        out = live & (t > t_far)
        p = o + t[:, None] * d
        f = implicit(p)
        first = jnp.isnan(f_prev)
        crossed = live & ~out & ~first & (jnp.sign(f) != jnp.sign(f_prev))
        bad = live & ~out & ~jnp.isfinite(f)
        lip = grid.lipschitz[tuple(_cell(grid, p).T)]
        safe = safety * jnp.abs(f) / lip
        closing = ~first & (jnp.abs(f) < jnp.abs(f_prev)) & (t > t_prev)
        drop = jnp.where(closing, f_prev - f, 1.0)
        secant = jnp.where(closing, 1.05 * f * (t - t_prev) / drop, 0.0)
        step = jnp.maximum(safe, jnp.minimum(secant, grid.h))
        step = jnp.clip(step, 0.25 * footprint * jnp.maximum(t, 0.0), 2 * grid.h)
        go = live & ~out & ~crossed & ~bad
        status = jnp.where(crossed, _BRACKET, jnp.where(out | bad, _MISS, status))
        t_prev = jnp.where(go, t, t_prev)
        f_prev = jnp.where(go, f, f_prev)
        f_now = jnp.where(crossed, f, f_now)
        t = jnp.where(go, t + step, t)
        return t, t_prev, f_prev, f_now, status

    return jax.lax.fori_loop(0, steps, body, (t, t_prev, f_prev, f_now, status))


@eqx.filter_jit
def _refine(implicit, o, d, ta, fa, tb, fb, n_bisect: int, n_illinois: int):
    """The root in each bracket [ta, tb] (f(ta), f(tb) of opposite signs): `n_bisect` bisection
    steps, `n_illinois` steps of the Illinois variant of regula falsi (superlinear, f only), then
    one Newton step along the ray with the directional derivative from `jax.jvp`, kept inside the
    bracket. Returns the depth, the point, f there and grad f (`_value_grad`), float64."""

    def f_at(t):
        return implicit(o + t[:, None] * d)

    def bisect(_, s):
        ta, fa, tb, fb = s
        tm = 0.5 * (ta + tb)
        fm = f_at(tm)
        left = jnp.sign(fm) == jnp.sign(fa)
        return (
            jnp.where(left, tm, ta),
            jnp.where(left, fm, fa),
            jnp.where(left, tb, tm),
            jnp.where(left, fb, fm),
        )

    ta, fa, tb, fb = jax.lax.fori_loop(0, n_bisect, bisect, (ta, fa, tb, fb))

    def illinois(_, s):
        ta, fa, tb, fb = s
        denom = fb - fa
        tc = jnp.where(
            denom == 0, 0.5 * (ta + tb), (ta * fb - tb * fa) / jnp.where(denom == 0, 1.0, denom)
        )
        fc = f_at(tc)
        flip = jnp.sign(fc) != jnp.sign(fb)  # the root lies between tb and tc
        done = fc == 0
        ta2 = jnp.where(flip, tb, ta)
        fa2 = jnp.where(flip, fb, 0.5 * fa)
        ta2, fa2 = jnp.where(done, tc, ta2), jnp.where(done, fc, fa2)
        return ta2, fa2, tc, fc

    ta, fa, tb, fb = jax.lax.fori_loop(0, n_illinois, illinois, (ta, fa, tb, fb))
    f, df = jax.jvp(implicit, (o + tb[:, None] * d,), (d,))
    tn = tb - f / jnp.where(df == 0, jnp.inf, df)
    ok = (tn >= jnp.minimum(ta, tb)) & (tn <= jnp.maximum(ta, tb)) & jnp.isfinite(tn)
    t = jnp.where(ok, tn, tb)
    p = o + t[:, None] * d
    f, g = _value_grad(implicit, p)
    return t, p, f, g


@eqx.filter_jit
def _occlusion(implicit, p, n, gnorm, radius, samples: int):
    """Ambient occlusion from `samples` points along the normal: how far the field's distance
    estimate f / |grad f| at p + s n falls short of s (0: open, 1: fully occluded)."""
    s = radius * (jnp.arange(1, samples + 1, dtype=p.dtype) / samples)
    q = p[:, None, :] + s[None, :, None] * n[:, None, :]
    f = implicit(q.reshape(-1, 3)).reshape(p.shape[0], samples)
    est = f / gnorm[:, None]
    w = 1.0 / jnp.arange(1, samples + 1, dtype=p.dtype)
    short = jnp.clip((s[None, :] - est) / s[None, :], 0.0, 1.0)
    return jnp.sum(w * short, axis=1) / jnp.sum(w)


@jax.jit
def _shade(albedo, n, view, lights, colours, lit, ao, ambient, specular, shininess):
    """Lambert + Blinn-Phong in linear RGB. `albedo` (m, 3) linear, `n` (m, 3) unit normals,
    `view` (m, 3) unit vectors towards the camera, `lights` (L, 3) unit directions towards the
    lights, `colours` (L, 3), `lit` (m, L) 0/1 shadow factors, `ao` (m,) occlusion in [0, 1]."""
    ndl = jnp.clip(n @ lights.T, 0.0, None)  # (m, L)
    half = view[:, None, :] + lights[None, :, :]
    half = half / jnp.maximum(jnp.linalg.norm(half, axis=-1, keepdims=True), 1e-12)
    ndh = jnp.clip(jnp.sum(n[:, None, :] * half, axis=-1), 0.0, None)
    spec = specular * ndh**shininess * (ndl > 0)
    diffuse = (lit * ndl) @ colours  # (m, 3)
    highlight = (lit * spec) @ colours
    sky = ambient * (1.0 - ao)[:, None]
    return albedo * (diffuse + sky) + highlight


# ------------------------------------------------------------------------------------ colours

_DIVERGING = np.array(
    [
        [0.230, 0.299, 0.754],
        [0.552, 0.690, 0.996],
        [0.865, 0.865, 0.865],
        [0.958, 0.604, 0.482],
        [0.706, 0.016, 0.150],
    ]
)


def _diverging(v: np.ndarray, vmin: float, vmax: float) -> np.ndarray:
    """A blue-grey-red diverging map of `v` over [vmin, vmax] (sRGB in [0, 1])."""
    x = np.clip((v - vmin) / (vmax - vmin if vmax > vmin else 1.0), 0.0, 1.0)
    pos = np.linspace(0.0, 1.0, len(_DIVERGING))
    return np.stack([np.interp(x, pos, _DIVERGING[:, k]) for k in range(3)], axis=-1)


def _to_linear(c):
    return np.asarray(c, dtype=float) ** 2.2


def _to_srgb8(c: np.ndarray) -> np.ndarray:
    return np.round(255 * np.clip(c, 0.0, 1.0) ** (1 / 2.2)).astype(np.uint8)


def _colour(name: str, c) -> np.ndarray:
    try:
        a = np.asarray(c, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"`{name}` must be an RGB triple in [0, 1], got {c!r}") from None
    if a.shape != (3,) or not np.all((a >= 0) & (a <= 1)):
        raise InputError(f"`{name}` must be an RGB triple in [0, 1], got {c!r}")
    return a


# ----------------------------------------------------------------------------- scalar colours


def mean_curvature(implicit: Callable, points) -> np.ndarray:
    """Mean curvature of the level set through each point, H = div(grad f / |grad f|) / 2
    = (|g|^2 tr(Hf) - g^T Hf g) / (2 |g|^3): positive where the surface is convex (1/R on a
    sphere of radius R with f growing outwards). The Hessian comes from forward-over-reverse
    differentiation (`jax.jvp` of `jax.grad`), float64."""
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"`points` must have shape (n, 3), got {p.shape}")
    if len(p) == 0:
        return np.zeros(0)
    (h,) = _in_chunks(lambda q: _curvature(implicit, q), [p], len(p))
    return h


@eqx.filter_jit
def _curvature(implicit, p):
    def grad(q):
        f, pullback = jax.vjp(implicit, q)
        return pullback(jnp.ones_like(f))[0]

    g = grad(p)
    cols = [jax.jvp(grad, (p,), (jnp.broadcast_to(e, p.shape),))[1] for e in jnp.eye(3)]
    hess = jnp.stack(cols, axis=2)  # (n, 3, 3)
    g2 = jnp.sum(g * g, axis=1)
    trace = jnp.trace(hess, axis1=1, axis2=2)
    ghg = jnp.einsum("ni,nij,nj->n", g, hess, g)
    return (g2 * trace - ghg) / (2 * jnp.maximum(g2, 1e-300) ** 1.5)


def mesh_error(reference, n: int = 200_000, seed: int = 0) -> Callable[[np.ndarray], np.ndarray]:
    """A function giving the signed distance from points to a reference mesh (positive outside,
    along the reference's outward normals), for `render(..., color_by=mesh_error(mesh))`.

    The reference is sampled area-uniformly at `n` points (`jaxrbf.metrics.sample_surface`) and
    each point takes the offset along the normal of its nearest sample (host, KD-tree): exact on
    flat parts, within the sample spacing elsewhere.
    """
    from scipy.spatial import cKDTree

    from .metrics import sample_surface

    samples, normals = sample_surface(reference, n, seed)
    tree = cKDTree(samples)

    def error(points: np.ndarray) -> np.ndarray:
        points = np.asarray(points, dtype=float)
        _, i = tree.query(points, workers=-1)
        return np.einsum("ij,ij->i", points - samples[i], normals[i])

    return error


# ------------------------------------------------------------------------------------- output


@dataclass
class Rendering:
    """What `render` produced.

    **Fields:**
    - `image`: (height, width, 3) uint8 sRGB.
    - `hit`: (height, width) bool, rays that met the surface.
    - `depth`: (height, width) distance from the camera along each ray (inf where no hit).
    - `points`, `normals`: (height, width, 3) hit points and unit normals (NaN where no hit).
    - `scalar`: (height, width) the values coloured by `color_by` (NaN elsewhere), or None.
    - `stats`: counts and timings: `rays`, `box_rays` (rays that met the bounding box), `hits`,
      `evaluations` (points at which f was evaluated while marching), `unfinished` (rays still
      marching after `max_steps`, shown as background), `unconverged` (hits whose distance
      estimate |f| / |grad f| is above `tol`), `band_cells`, `seconds`.
    """

    image: np.ndarray
    hit: np.ndarray
    depth: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    scalar: np.ndarray | None = None
    stats: dict = field(default_factory=dict)

    def save(self, path) -> None:
        """Write `image` to a PNG file, atomically."""
        save_png(path, self.image)


def save_png(path, image) -> None:
    """Write an (h, w, 3) or (h, w) uint8 image (or floats in [0, 1]) to `path` (.png) atomically,
    through Pillow."""
    from PIL import Image

    from .io import atomic_output

    p = os.fspath(path)
    ext = os.path.splitext(p)[1].lower()
    if ext not in _IMAGE_EXTS:
        got = f"'{ext}'" if ext else "no extension"
        raise InputError(
            f"cannot write an image to '{p}' ({got}); supported: {', '.join(_IMAGE_EXTS)}"
        )
    a = np.asarray(image)
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] not in (3, 4)) or a.size == 0:
        raise InputError(f"`image` must have shape (h, w), (h, w, 3) or (h, w, 4), got {a.shape}")
    if a.dtype != np.uint8:
        a = np.round(255 * np.clip(np.nan_to_num(a.astype(float)), 0, 1)).astype(np.uint8)
    with atomic_output(p) as tmp:
        Image.fromarray(a).save(tmp, format="PNG", optimize=True)


# ------------------------------------------------------------------------------------- render


def _box_entry(o, d, lo, hi):
    """Slab test on the host: (t_near, t_far, hit) per ray against the box [lo, hi]."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t1, t2 = (lo - o) * inv, (hi - o) * inv
    t1 = np.where(d == 0, np.where((o >= lo) & (o <= hi), -np.inf, np.inf), t1)
    t2 = np.where(d == 0, np.where((o >= lo) & (o <= hi), np.inf, -np.inf), t2)
    near = np.max(np.minimum(t1, t2), axis=1)
    far = np.min(np.maximum(t1, t2), axis=1)
    return np.maximum(near, 0.0), far, far >= np.maximum(near, 0.0)


def _trace(implicit, grid, o, d, t0, t_far, footprint, safety, max_steps, bar):
    """March rays in wavefront rounds; returns (status, t_a, f_a, t_b, f_b, unfinished,
    evaluations)."""
    m = len(o)
    t = t0.copy()
    t_prev = t0.copy()
    f_prev = np.full(m, np.nan)
    f_now = np.full(m, np.nan)
    status = np.zeros(m, np.int32)
    evaluations = 0
    alive = np.arange(m)
    for _ in range(-(-max_steps // _ROUND)):
        if len(alive) == 0:
            break
        n = len(alive)
        evaluations += n * _ROUND
        arrays = [o, d, t, t_far, t_prev, f_prev, f_now, status]
        arrays = [a[alive] for a in arrays]
        pad = -n % _CHUNK
        if pad:  # padding rays are missed already: they take no steps
            arrays = [
                np.concatenate([a, np.broadcast_to(a[:1], (pad,) + a.shape[1:])]) for a in arrays
            ]
            arrays[7][n:] = _MISS
        res = _in_chunks(
            lambda *a: _march(
                implicit, grid, *a, jnp.asarray(footprint), jnp.asarray(safety), _ROUND
            ),
            arrays,
            len(arrays[0]),
            bar=bar,
        )
        t[alive], t_prev[alive], f_prev[alive], f_now[alive], status[alive] = (r[:n] for r in res)
        alive = alive[status[alive] == _ACTIVE]
    unfinished = status == _ACTIVE
    status[unfinished] = _MISS
    return status, t_prev, f_prev, t, f_now, unfinished, evaluations


def render(
    implicit: Callable,
    camera: Camera | None = None,
    *,
    bounds=None,
    padding: float = 0.02,
    color=(0.80, 0.76, 0.68),
    background=None,
    lights: Sequence | None = None,
    shadows: bool = False,
    ambient_occlusion: bool = False,
    color_by: str | Callable | None = None,
    color_range: tuple[float, float] | None = None,
    grid: int = 32,
    band: float = 1.5,
    safety: float = 0.9,
    max_steps: int = 256,
    tol: float = 1e-6,
    progress: bool | None = None,
) -> Rendering:
    """Ray-march a picture of the surface f = 0 of a 3-D implicit.

    **Arguments:**
    - `implicit`: an `RBFModel`, `PartitionModel`, a `jaxrbf.csg` shape, or any JAX-traceable
      callable mapping (n, 3) points to (n,) values (f < 0 inside, f > 0 outside).
    - `camera`: a `Camera`; default `Camera.orbit(bounds)` (azimuth 30, elevation 20, y up,
      512 x 512).
    - `bounds`: `(lo, hi)` of the region to draw; default the implicit's `bounds()` grown by
      `padding` of its largest side. Rays that miss it are background.
    - `color`: the surface's RGB in [0, 1]. `background`: an RGB, or None for a soft vertical
      gradient.
    - `lights`: up to two `(direction, rgb)` pairs, directions in the camera's frame (x right,
      y up, z towards the viewer); default a key light from the upper left and a dim fill light
      from the right.
    - `shadows`: cast a shadow ray from each hit to the key light (marched like the primary rays:
      about doubles the time). `ambient_occlusion`: darken creases from 6 extra evaluations of f
      per hit along the normal.
    - `color_by`: `"curvature"` (mean curvature, `mean_curvature`), or a function of the (k, 3)
      hit points returning k values (e.g. `mesh_error(reference)` for the signed error against a
      reference mesh); drawn with a blue-grey-red diverging map over `color_range` (default
      symmetric about 0, at the 98th percentile of |value|).
    - `grid`, `band`, `safety`, `max_steps`: the marching (see the module's docstring): coarse
      grid cells along the longest side, band width in cell diagonals, step safety factor in
      (0, 1], and the step limit per ray. `tol`: a hit counts as converged when
      |f| / |grad f| < `tol` times the box's diagonal.
    - `progress`: progress bars on stderr (default: when stderr is a terminal).

    **Returns:** a `Rendering` (image, hit mask, depth, points, normals, statistics); save it
    with `Rendering.save("view.png")`.
    """
    start = time.perf_counter()
    if getattr(implicit, "dim", 3) != 3:
        raise InputError(
            f"render draws 3-D implicits; this one is {implicit.dim}-D (see jaxrbf.plot)"
        )
    if bounds is None and not hasattr(implicit, "bounds"):
        raise InputError(
            "`bounds` is needed for an implicit that does not know its extent: give bounds=(lo, hi)"
        )
    lo, hi = _box(implicit.bounds() if bounds is None else bounds)
    if bounds is None:
        pad = float(padding) * float((hi - lo).max())
        lo, hi = lo - pad, hi + pad
    if np.any(hi <= lo):
        raise InputError(f"`bounds` must have hi > lo on every axis, got lo={lo}, hi={hi}")
    if camera is None:
        camera = Camera.orbit((lo, hi))
    if not isinstance(camera, Camera):
        raise InputError(f"`camera` must be a jaxrbf.render.Camera, got {type(camera).__name__}")
    if not (0 < float(safety) <= 1):
        raise InputError(f"`safety` must be in (0, 1], got {safety}")
    if int(grid) < 2 or int(max_steps) < 1 or not float(band) > 0:
        raise InputError(
            f"`grid` must be >= 2, `max_steps` >= 1 and `band` > 0; got {grid}, {max_steps}, {band}"
        )
    albedo0 = _colour("color", color)
    bg = None if background is None else _colour("background", background)
    lights = _lights(lights, camera)
    if color_by is not None and not (color_by == "curvature" or callable(color_by)):
        raise InputError(
            f"`color_by` must be 'curvature' or a function of the hit points, got {color_by!r}"
        )

    w, h = camera.size
    diag = float(np.linalg.norm(hi - lo))
    o_all, d_all = camera.rays()
    t0, t_far, in_box = _box_entry(o_all, d_all, lo, hi)
    rays = np.flatnonzero(in_box)
    footprint = 2 * np.tan(np.radians(camera.fov) / 2) / h  # pixel size per unit of depth

    cells = int(grid)
    n_grid = int(np.prod(np.ceil((hi - lo) / ((hi - lo).max() / cells)) + 1))
    with progress_bar(-(-n_grid // _CHUNK), "render: grid", "chunk", progress) as bar:
        accel, band_cells = _build_grid(implicit, lo, hi, cells, float(band), bar)

    with progress_bar(0, "render: marching", "chunk", progress) as bar:
        status, ta, fa, tb, fb, unfinished, evaluations = _trace(
            implicit,
            accel,
            o_all[rays],
            d_all[rays],
            t0[rays],
            t_far[rays],
            footprint,
            float(safety),
            int(max_steps),
            bar,
        )
        sel = status == _BRACKET
        hits = rays[sel]
        ta, fa, tb, fb = ta[sel], fa[sel], tb[sel], fb[sel]
        if len(hits):
            t, p, f, g = _in_chunks(
                lambda *a: _refine(implicit, *a, 2, 5),
                [o_all[hits], d_all[hits], ta, fa, tb, fb],
                len(hits),
            )
        else:
            t, p, f, g = np.zeros(0), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3))

    gnorm = np.linalg.norm(g, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        normals = g / gnorm[:, None]
        est = np.abs(f) / gnorm
    unconverged = int(np.sum(~(est < tol * diag)))

    # scalar colouring
    scalar = None
    if color_by is not None and len(hits):
        vals = (
            mean_curvature(implicit, p)
            if color_by == "curvature"
            else np.asarray(color_by(p), dtype=float).reshape(-1)
        )
        if vals.shape != (len(hits),):
            raise InputError(f"`color_by` returned {vals.shape} values for {len(hits)} hit points")
        if color_range is None:
            finite = np.abs(vals[np.isfinite(vals)])
            top = float(np.percentile(finite, 98)) if finite.size else 1.0
            top = top if top > 0 else 1.0
            vmin, vmax = -top, top
        else:
            vmin, vmax = (float(x) for x in color_range)
        albedo = _to_linear(_diverging(np.nan_to_num(vals), vmin, vmax))
        scalar = np.full(w * h, np.nan)
        scalar[hits] = vals
        scalar = scalar.reshape(h, w)
    else:
        albedo = np.broadcast_to(_to_linear(albedo0), (len(hits), 3))

    # lights, shadows, occlusion
    lit = np.ones((len(hits), len(lights[0])))
    if shadows and len(hits):
        key = lights[0][0]
        facing = normals @ key > 0
        idx = np.flatnonzero(facing)
        if len(idx):
            so = p[idx] + normals[idx] * (1e-3 * diag)
            sd = np.broadcast_to(key, so.shape).copy()
            s0, sfar, _ = _box_entry(so, sd, lo, hi)
            with progress_bar(0, "render: shadows", "chunk", progress) as bar:
                st, *_ = _trace(
                    implicit, accel, so, sd, s0, sfar, footprint, float(safety), int(max_steps), bar
                )
            lit[idx[st == _BRACKET], 0] = 0.0
    ao = np.zeros(len(hits))
    if ambient_occlusion and len(hits):
        (ao,) = _in_chunks(
            lambda p_, n_, g_: _occlusion(implicit, p_, n_, g_, 0.04 * diag, 6),
            [p, normals, gnorm],
            len(hits),
        )
        ao = np.clip(1.3 * ao, 0.0, 1.0)

    colours = np.zeros((w * h, 3))
    if len(hits):
        view = -d_all[hits]
        rgb = _shade(
            jnp.asarray(albedo),
            jnp.asarray(np.nan_to_num(normals)),
            jnp.asarray(view),
            jnp.asarray(lights[0]),
            jnp.asarray(lights[1]),
            jnp.asarray(lit),
            jnp.asarray(ao),
            0.32,
            0.25,
            40.0,
        )
        colours[hits] = np.asarray(rgb)
    colours = colours.reshape(h, w, 3)
    mask = np.zeros(w * h, bool)
    mask[hits] = True
    mask = mask.reshape(h, w)
    if bg is None:
        rows = np.linspace(0.0, 1.0, h)[:, None]
        top, bottom = _to_linear((0.93, 0.94, 0.96)), _to_linear((1.0, 1.0, 1.0))
        back = (1 - rows) * top + rows * bottom
        back = np.broadcast_to(back[:, None, :], (h, w, 3))
    else:
        back = np.broadcast_to(_to_linear(bg), (h, w, 3))
    image = _to_srgb8(np.where(mask[..., None], colours, back))

    depth = np.full(w * h, np.inf)
    depth[hits] = t
    pts = np.full((w * h, 3), np.nan)
    pts[hits] = p
    nrm = np.full((w * h, 3), np.nan)
    nrm[hits] = normals
    stats = dict(
        rays=w * h,
        box_rays=len(rays),
        hits=len(hits),
        evaluations=int(evaluations),
        unfinished=int(unfinished.sum()),
        unconverged=unconverged,
        band_cells=int(band_cells.sum()),
        seconds=time.perf_counter() - start,
    )
    return Rendering(
        image, mask, depth.reshape(h, w), pts.reshape(h, w, 3), nrm.reshape(h, w, 3), scalar, stats
    )


def _lights(lights, camera: Camera):
    """World directions (L, 3) towards the lights and their colours (L, 3), from directions in
    the camera's frame."""
    if lights is None:
        lights = [((-0.5, 0.7, 0.6), (0.95, 0.93, 0.88)), ((0.8, 0.1, 0.4), (0.25, 0.27, 0.32))]
    try:
        lights = list(lights)
    except TypeError:
        raise InputError("`lights` must be a list of (direction, rgb) pairs") from None
    if not 1 <= len(lights) <= 2:
        raise InputError(f"`lights` must hold one or two (direction, rgb) pairs, got {len(lights)}")
    f, r, u = camera.basis()
    dirs, cols = [], []
    for k, light in enumerate(lights):
        try:
            direction, rgb = light
        except (TypeError, ValueError):
            raise InputError(f"light {k} must be a (direction, rgb) pair, got {light!r}") from None
        v = _vec(f"light {k} direction", direction)
        if np.linalg.norm(v) == 0:
            raise InputError(f"light {k} direction must be non-zero")
        world = v[0] * r + v[1] * u - v[2] * f
        dirs.append(world / np.linalg.norm(world))
        c = np.asarray(rgb, dtype=float).reshape(-1)
        if c.shape != (3,) or not np.all(np.isfinite(c)) or np.any(c < 0):
            raise InputError(f"light {k} colour must be 3 non-negative numbers, got {rgb!r}")
        cols.append(c)
    return np.array(dirs), np.array(cols)
