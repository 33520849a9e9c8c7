"""Zero sets to meshes and curves: the grid is sampled in JAX (fixed-size chunks, jit), then
scikit-image's marching cubes / find_contours run on the host. Works on any implicit: a JAX-traceable
callable mapping (n, d) points to (n,) values."""

from __future__ import annotations

import sys
from collections.abc import Callable

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._errors import InputError
from ._project import project as _project

_CHUNK = 2**15


def _bounds(implicit, bounds, dim: int | None, padding: float):
    if bounds is None:
        if not hasattr(implicit, "bounds"):
            raise InputError(
                "`bounds` is needed for an implicit that does not know its extent: "
                "give bounds=(lo, hi), e.g. ((-1, -1, -1), (1, 1, 1))"
            )
        lo, hi = (np.asarray(b, dtype=float) for b in implicit.bounds())
        pad = padding * (hi - lo).max()
        lo, hi = lo - pad, hi + pad
    else:
        try:
            lo, hi = (np.asarray(b, dtype=float).reshape(-1) for b in bounds)
        except (TypeError, ValueError):
            raise InputError("`bounds` must be a pair (lo, hi) of coordinate tuples") from None
    if lo.shape != hi.shape or (dim is not None and lo.shape != (dim,)):
        raise InputError(
            f"`bounds` must be two points of dimension {dim}, got {lo.shape} and {hi.shape}"
        )
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
        raise InputError(
            f"`bounds` must be finite with hi > lo on every axis, got lo={lo}, hi={hi}"
        )
    return lo, hi


def _grid_shape(lo, hi, resolution) -> tuple[np.ndarray, tuple[int, ...]]:
    ext = hi - lo
    if np.ndim(resolution) == 0:
        res = int(resolution)
        if res < 2:
            raise InputError(f"`resolution` must be at least 2 samples, got {resolution}")
        h = ext.max() / (res - 1)
        shape = tuple(int(np.ceil(e / h)) + 1 for e in ext)
        return np.full(len(ext), h), shape
    res = tuple(int(r) for r in resolution)
    if len(res) != len(ext) or min(res) < 2:
        raise InputError(f"`resolution` must be an int or {len(ext)} ints >= 2, got {resolution}")
    return ext / (np.array(res) - 1), res


@eqx.filter_jit
def _eval_chunk(implicit, lo, h, shape, start, chunk: int):
    idx = start + jnp.arange(chunk)
    coords = []
    rest = idx
    for k in range(len(shape) - 1, -1, -1):
        coords.append(rest % shape[k])
        rest = rest // shape[k]
    ijk = jnp.stack(coords[::-1], axis=1)
    pts = lo + ijk * h
    return implicit(pts)


def sample_grid(
    implicit: Callable, lo, hi, resolution, *, progress: bool | None = None, desc: str = "sampling"
) -> tuple[np.ndarray, np.ndarray]:
    """Values of `implicit` on a regular grid over [lo, hi] (float64 on the host).

    **Returns:** `(values, spacing)`: an array of the grid's shape (axis k = coordinate k) and the
    spacing per axis.
    """
    from tqdm import tqdm

    spacing, shape = _grid_shape(np.asarray(lo, float), np.asarray(hi, float), resolution)
    total = int(np.prod(shape))
    out = np.empty(total)
    n_chunks = -(-total // _CHUNK)
    disable = (not sys.stderr.isatty()) if progress is None else not progress
    lo_j, h_j = jnp.asarray(lo, dtype=float), jnp.asarray(spacing)
    for c in tqdm(range(n_chunks), desc=desc, unit="chunk", disable=disable, file=sys.stderr):
        start = c * _CHUNK
        vals = np.asarray(_eval_chunk(implicit, lo_j, h_j, shape, jnp.asarray(start), _CHUNK))
        end = min(start + _CHUNK, total)
        out[start:end] = vals[: end - start]
    out = out.reshape(shape)
    bad = ~np.isfinite(out)
    if bad.any():
        raise InputError(
            f"the implicit returned NaN or infinite values at {int(bad.sum())} of {total} grid points"
        )
    return out, spacing


def polygonize(
    implicit: Callable,
    resolution: int | tuple[int, int, int] = 128,
    bounds=None,
    *,
    level: float = 0.0,
    project: bool = False,
    padding: float = 0.05,
    progress: bool | None = None,
):
    """Mesh the level set f = `level` of a 3-D implicit with marching cubes.

    **Arguments:**
    - `implicit`: an `RBFModel` or any JAX-traceable callable mapping (n, 3) points to (n,) values.
    - `resolution`: samples along the longest side of the box (cubic voxels), or one per axis.
    - `bounds`: `(lo, hi)`; default for a model: its centres' box grown by `padding` of its size.
    - `level`: the iso-value. `project`: Newton-project the vertices onto f = level with the
      analytic gradient (closer to the true surface than marching cubes' linear interpolation).
    - `progress`: a progress bar on stderr (default: when stderr is a terminal).

    **Returns:** a `jaxrbf.io.Mesh` (vertices in world coordinates, faces oriented outward: their
    normals point to increasing f).
    """
    from skimage.measure import marching_cubes

    from .io import Mesh

    lo, hi = _bounds(implicit, bounds, 3, padding)
    vol, spacing = sample_grid(implicit, lo, hi, resolution, progress=progress, desc="meshing")
    if not (vol.min() < level < vol.max()):
        raise InputError(
            f"f never crosses level {level} inside the bounds (values from {vol.min():.3g} to "
            f"{vol.max():.3g}): widen `bounds` or check the fit"
        )
    verts, faces, normals, _ = marching_cubes(
        vol, level, spacing=tuple(spacing), allow_degenerate=False
    )
    verts = verts + lo
    faces = faces.astype(np.int64)
    # marching_cubes' normals point down the gradient ('descent'); ours should point up it.
    tri = verts[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    if np.sum(fn * normals[faces].sum(axis=1)) > 0:
        faces = faces[:, ::-1].copy()
    if project:
        moved, ok = _project(implicit, verts, level=level, max_step=float(spacing.max()))
        verts = np.where(ok[:, None], moved, verts)
    return Mesh(verts, faces)


def contour(
    implicit: Callable,
    resolution: int | tuple[int, int] = 256,
    bounds=None,
    *,
    level: float = 0.0,
    padding: float = 0.05,
    progress: bool | None = None,
) -> list[np.ndarray]:
    """Curves of f = `level` of a 2-D implicit (marching squares, `skimage.measure.find_contours`).

    **Arguments:** as for `polygonize`, for (n, 2) points.

    **Returns:** a list of (k, 2) arrays in world coordinates; a closed curve repeats its first
    vertex at the end.
    """
    from skimage.measure import find_contours

    lo, hi = _bounds(implicit, bounds, 2, padding)
    grid, spacing = sample_grid(implicit, lo, hi, resolution, progress=progress, desc="contouring")
    return [lo + c * spacing for c in find_contours(grid, level)]
