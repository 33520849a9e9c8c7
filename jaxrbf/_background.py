"""Backgrounds for surface fits with kernels that decay (Gaussian, inverse multiquadric, Wendland).

Such a fit, f = sum_j w_j phi(|x - c_j|) + p(x), is its bare first-degree polynomial p wherever
no centre is within a few radii, and p (a plane) crosses zero somewhere in the meshing box: a
spurious sheet of surface that no error measured on the samples can see. Measured on the fandisk
(2,000 samples, Gaussian kernel, a 7 x 7 grid of offsets and radii around the defaults): 13-60%
of the box beyond three point spacings from the samples had the wrong sign, and the Chamfer
distance of the mesh was 0.7-1.9% of the diagonal wherever the fit succeeded.

The remedy is the partition of unity's own (`jaxrbf._partition`): a coarse global fit with the
right sign everywhere, here a polyharmonic fit (r^3 in 3-D, r^2 log r in 2-D) of a subsample of
the surface samples with their off-surface points (`coarse_constraints`), and the decaying kernel
fitted to what it leaves: f = g + sum_j w_j phi + p through the same constraints
(`jaxrbf.fit(..., background=g)`). Far from the data f -> g + p, with p small (it only absorbs the
trend of the residual).

Measured (2,000 samples, default offset and radius, mesh at resolution 128, Chamfer-L1 in % of
the diagonal):
- Gaussian: spot 0.85% -> 0.18%, the bunny 0.91% -> 0.28%, the fandisk 1.86% -> 0.32% (there,
  with a 500-sample background, the wrong-sign fraction fell from 13% to 0.05%);
- Wendland with its radius at `support_floor` (which already covers the box): about even or
  worse, spot 0.159% -> 0.160%, the bunny 0.21% -> 0.24%, the fandisk 0.228% -> 0.234%;
- the background's own quality matters: on 500 samples it is poor where the bunny is thin (1.71%
  alone; the Gaussian over it 1.18%); on 1,000 (the default here) 0.30% alone.

So the surface-level paths (`tune`, `grid_search`, the objectives when asked, `fit_surface` with
the dense method) add it for the kernels of `DECAYING` (`background="auto"`), not for Wendland:
its radius is kept at `support_floor`, which already covers the box. The background is built on
the host from concrete samples and is a constant of the fit (no gradient flows into it).
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict

import jax
import numpy as np

#: Surface samples of a background (all of them when there are fewer): 3,000 constraints, one
#: dense solve of about a second. 500 were too few on the bunny (see above).
BACKGROUND_SAMPLES = 1000
#: Backgrounds kept, keyed by a hash of their samples (tuning, its grid search and the final fit
#: ask for the same ones again).
_CACHE: OrderedDict[str, object] = OrderedDict()
_CACHE_SIZE = 8


#: Kernels whose surface fits get a background by default (`background="auto"`).
DECAYING = ("gaussian", "inverse-multiquadric")


def wants_background(background, kernel: str) -> bool:
    """Whether a surface fit with the kernel named `kernel` gets a background: `background` is
    "auto" (the kernels of `DECAYING`), True or False."""
    from ._prepare import auto_flag

    return auto_flag(background, "background", kernel in DECAYING)


def surface_background(points, normals, *, seed: int = 0):
    """The background of a surface fit: a global polyharmonic `RBFModel` of a random subsample of
    `BACKGROUND_SAMPLES` of the surface samples `points` with their outward `normals`, with
    off-surface points at two of the subsample's point spacings. Pass it as
    `jaxrbf.fit(..., background=...)`; see the module docstring. Float64, LU; host (safe to call
    while JAX traces: it runs eagerly)."""
    from ._constraints import checked_samples
    from ._fit import fit
    from ._partition import coarse_constraints

    p, nrm = checked_samples(points, normals)
    key = hashlib.sha1(p.tobytes() + nrm.tobytes() + str((p.shape, seed)).encode()).hexdigest()
    if key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key]
    keep = min(len(p), BACKGROUND_SAMPLES)
    rng = np.random.default_rng(seed)
    pick = np.sort(rng.choice(len(p), keep, replace=False))
    with jax.ensure_compile_time_eval():
        xc, hc = coarse_constraints(p[pick], nrm[pick])
        model = fit(
            xc,
            hc,
            kernel="cubic" if p.shape[1] == 3 else "thin-plate",
            solver="lu",
            method="dense",
        )
    _CACHE[key] = model
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return model
