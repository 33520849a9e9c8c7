"""2-D pictures of implicits through matplotlib: the scalar field as a diverging colour map, its
zero contour, other level contours and the constraint points (the paper's Fig. 4).

matplotlib is imported when a function here is called (install it with `pip install
"jaxrbf[plot]"`); the field is sampled with `jaxrbf`'s grid sampler (jit-compiled, fixed-size
chunks, float64).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence

import numpy as np

from ._errors import InputError

__all__ = ["plot_field"]

_FIGURE_EXTS = (".png", ".pdf", ".svg")


def _pyplot():
    try:
        import matplotlib

        if os.environ.get("MPLBACKEND") is None and not _interactive():
            matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise InputError(
            'plotting needs matplotlib, which is not installed: pip install "jaxrbf[plot]" '
            "(or pip install matplotlib)"
        ) from None
    return plt


def _interactive() -> bool:
    import sys

    return "ipykernel" in sys.modules or hasattr(sys, "ps1")


def _constraint_arrays(constraints):
    if constraints is None:
        return None
    if hasattr(constraints, "points") and hasattr(constraints, "values"):
        p, v = constraints.points, constraints.values
    else:
        try:
            p, v = constraints
        except (TypeError, ValueError):
            raise InputError(
                "`constraints` must be a jaxrbf.Constraints or a (points, values) pair"
            ) from None
    p = np.asarray(p, dtype=float)
    v = np.asarray(v, dtype=float).reshape(-1)
    if p.ndim != 2 or p.shape[1] != 2 or len(p) != len(v):
        raise InputError(
            f"`constraints` must hold (n, 2) points and (n,) values, got {p.shape} and {v.shape}"
        )
    return p, v


def plot_field(
    implicit: Callable,
    bounds=None,
    *,
    resolution: int = 256,
    levels: int | Sequence[float] = 8,
    constraints=None,
    ax=None,
    cmap: str = "RdBu_r",
    padding: float = 0.1,
    colorbar: bool = True,
    title: str | None = None,
    path=None,
):
    """Draw the scalar field of a 2-D implicit with its zero contour (the paper's Fig. 4).

    **Arguments:**
    - `implicit`: a 2-D `RBFModel`, a 2-D `jaxrbf.csg` shape, or any JAX-traceable callable
      mapping (n, 2) points to (n,) values.
    - `bounds`: `(lo, hi)` of the window; default the implicit's `bounds()` grown by `padding`
      of its largest side.
    - `resolution`: samples along the longer side.
    - `levels`: the other contours: a number of levels spread over the field's range, or the
      values themselves (0 is always drawn, thick and black).
    - `constraints`: a `jaxrbf.Constraints` (or a `(points, values)` pair) to mark: on-surface
      points (value 0) as black dots, outside (value > 0) as red plus signs, inside (< 0) as
      blue minus signs.
    - `ax`: a matplotlib Axes to draw into (default: a new figure). `cmap`: a diverging colour
      map, centred on 0. `colorbar`, `title`: as in matplotlib.
    - `path`: also save the figure there (`.png`, `.pdf`, `.svg`), atomically.

    **Returns:** the matplotlib Axes.
    """
    from ._polygonize import _bounds, sample_grid
    from .io import atomic_output

    if path is not None:
        ext = os.path.splitext(os.fspath(path))[1].lower()
        if ext not in _FIGURE_EXTS:
            got = f"'{ext}'" if ext else "no extension"
            raise InputError(
                f"cannot save a figure to '{os.fspath(path)}' ({got}); supported: "
                f"{', '.join(_FIGURE_EXTS)}"
            )
    dim = getattr(implicit, "dim", 2)
    if dim != 2:
        raise InputError(f"plot_field draws 2-D implicits; this one is {dim}-D (see jaxrbf.render)")
    pts = _constraint_arrays(constraints)
    plt = _pyplot()
    from matplotlib.colors import TwoSlopeNorm

    lo, hi = _bounds(implicit, bounds, 2, padding)
    vals, spacing = sample_grid(implicit, lo, hi, resolution, progress=False, desc="plotting")
    xs = lo[0] + spacing[0] * np.arange(vals.shape[0])
    ys = lo[1] + spacing[1] * np.arange(vals.shape[1])
    grid_x, grid_y = np.meshgrid(xs, ys, indexing="ij")

    if ax is None:
        _, ax = plt.subplots(figsize=(6, 6 * (hi[1] - lo[1]) / (hi[0] - lo[0]) + 0.4))
    top = float(np.abs(vals).max()) or 1.0
    norm = TwoSlopeNorm(vcenter=0.0, vmin=-top, vmax=top)
    image = ax.pcolormesh(grid_x, grid_y, vals, cmap=cmap, norm=norm, shading="auto")
    if isinstance(levels, (int, np.integer)):
        if levels < 0:
            raise InputError(
                f"`levels` must be a non-negative count or a list of values, got {levels}"
            )
        others = np.linspace(vals.min(), vals.max(), int(levels) + 2)[1:-1]
    else:
        others = np.asarray(levels, dtype=float).reshape(-1)
    others = np.sort(others[np.abs(others) > 1e-12 * top])
    if len(others):
        ax.contour(grid_x, grid_y, vals, levels=others, colors="0.25", linewidths=0.6, alpha=0.7)
    if vals.min() < 0 < vals.max():
        ax.contour(grid_x, grid_y, vals, levels=[0.0], colors="k", linewidths=2.0)
    if pts is not None:
        p, v = pts
        scale = max(float(np.abs(v).max()), 1e-300)
        on = np.abs(v) <= 1e-12 * scale
        for mask, marker, colour, label in (
            (on, "o", "k", "on (0)"),
            (~on & (v > 0), "+", "#b2182b", "outside (> 0)"),
            (~on & (v < 0), "_", "#2166ac", "inside (< 0)"),
        ):
            if mask.any():
                ax.scatter(
                    p[mask, 0], p[mask, 1], marker=marker, c=colour, s=28, label=label, zorder=3
                )
        ax.legend(loc="upper right", fontsize=8, framealpha=0.85)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    if colorbar:
        ax.figure.colorbar(image, ax=ax, shrink=0.8, label="f")
    if title:
        ax.set_title(title)
    if path is not None:
        with atomic_output(path) as tmp:
            ax.figure.savefig(tmp, dpi=150, bbox_inches="tight")
    return ax
