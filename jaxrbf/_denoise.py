"""`choose_smoothing`: the smoothing lambda for a noisy point cloud, chosen by the held-out error.

An interpolating fit reproduces the scanner's noise as bumps; with smoothing lambda > 0 the system
is A + lambda I and the fit approximates. How much is right depends on the noise, the point
density and the kernel, so it is chosen by the tuning objective (`jaxrbf.objectives.held_out_error`): a fit
that follows the noise passes further from held-out samples (and its normals turn further from
theirs) than one that follows the surface underneath.

The choice is made on a few crops of the cloud at its own density (the k nearest neighbours of a
random sample): a crop holds as many points per patch as the real fit, so the lambda it picks means
the same there, whether the full fit is dense or a partition of unity, for any number of points.
Each crop's held-out points are taken from its interior only (its rim has no data beyond it).

Every candidate lambda of a crop comes from one symmetric eigendecomposition: with Q1 an
orthonormal basis of the polynomial block P and Pi = I - Q1 Q1^T, the weights of (A + lambda I)
w + P c = h, P^T w = 0 are w = V (L + lambda)^-1 V^T Pi h, where V L V^T = Pi A Pi + Q1 Q1^T, and
c follows from P c = h - (A + lambda I) w. So a fine grid of lambdas (quarter decades, in units of
diagonal^h so that a choice does not depend on the input's units) costs one O(n^3) step per crop,
and one compilation serves every crop of a size class (the systems are zero-padded to a multiple
of `PAD`). Float64 throughout (the interpolating end of the grid is as ill-conditioned as the
fit itself); a candidate whose shifted eigenvalues are not all positive counts as failed.

The held-out error of noisy samples is flat around its minimum, and the fit that wins there
follows the noise more than the measured Chamfer distance to the true surface wants (on the
fandisk at 0.5% noise, the minimum of the held-out error sat at a tenth of the lambda that is best
against the true surface). So the choice follows the one-standard-error rule of cross-validation
(Breiman et al. 1984; Hastie, Tibshirani and Friedman, section 7.10): the largest lambda, going
up from the minimum, whose mean held-out error stays within one standard error of the minimum's.
Interpolation (lambda = 0) is one of the candidates: clean input keeps it, or a lambda too small
to change the surface.

The held-out error can also ask for more smoothing than the noise explains. Its normals' term
compares each fit with the samples' normals, and a bare cloud's normals are estimated: plane fits
of 30 neighbours, a smoothing of the same points at that scale whatever the noise. Detail finer
than those neighbourhoods then scores as error, and the choice flattens it. So the choice is
bounded by the noise itself (after Morozov's discrepancy principle): a surface that removed just
the noise, of sigma across the surface (`jaxrbf.estimate_noise`), lies a median 0.6745 sigma from
the samples (the median of |N(0, 1)|); where the crops' fits at the chosen lambda pass a median
further than `DISCREPANCY` = 1 sigma from their own samples, the choice goes down the grid to the
largest lambda within it. On the noisy meshes and virtual scans of the benchmarks the choice lands
at 0.55-0.78 sigma and stands. On a real scan of a leg (noise 0.14 point spacings) it was 1.96
sigma (lambda 1e-5 diagonal^3; the full fit 1.1 sigma from the scan, farther than Poisson's
surface), and is lowered to 3.2e-8 (0.88 sigma).

The grid runs from 1e-8 to 1 diagonal^h. Real scans can want more (ten merged range scans of
362,000 points, misregistered, chose 0.1, the top of the grid as it was): when the choice is the
top, the grid is extended upward by two decades at a time (at most `MAX_EXTENSIONS` times), from
the eigendecompositions already made, so an extension costs only the held-out errors of its
candidates, until the choice falls inside it or the top passes `SATURATION` times the crops'
largest eigenvalue, beyond which every candidate is the crop's polynomial and the choice cannot
change. The report says when it extended, and when the choice is still the top.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._constraints import log
from ._errors import InputError

#: Points per crop: 1,000 points (about 2,600 constraints; one eigendecomposition ~2 s).
CROP_POINTS = 1000
#: Crops per choice; their held-out points are pooled.
CROPS = 3
#: Candidate lambdas, in units of diagonal^h: 0 (interpolation), then quarter decades from 1e-8
#: to 1 (up to 0.1 before: ten merged real range scans of 362,000 points chose its top).
GRID = (0.0, *(float(10.0 ** (e / 4)) for e in range(-32, 1)))
#: When the choice is the top of the grid, `EXTENSION` more quarter decades are tried above it
#: (from the same eigendecompositions: no new O(n^3) step), at most `MAX_EXTENSIONS` times ...
EXTENSION = 8
MAX_EXTENSIONS = 4
#: ... and never beyond `SATURATION` times the largest eigenvalue of any crop's system, where
#: every candidate is the crop's polynomial plus a kernel part below 1% of it.
SATURATION = 100.0
#: Held-out points are the crop's points within this fraction of its radius from its centre;
#: a third of those are held out.
INTERIOR = 0.6
#: Constraint counts are padded up to a multiple of this (fewer compilations).
PAD = 128
#: The choice is lowered while the crops' fits pass further than this many noise sigmas (median)
#: from their own samples. A surface that removed exactly the (Gaussian) noise lies a median
#: 0.6745 sigma from them (the median of |N(0, 1)|), and the held-out error's choices on noisy
#: inputs land at 0.55-0.78 sigma: 1 is a bound, not a target (more than half of the samples
#: further than one sigma, where the noise puts 32% of them), which none of those choices meets.
DISCREPANCY = 1.0


@dataclass
class SmoothingReport:
    """What `choose_smoothing` did. `smoothing` is in the points' units (give it to `fit`);
    `relative` is it in units of diagonal^h; `grid` and `objective` the candidates (relative) and
    their mean held-out error over the crops' held-out points (inf: the fit failed);
    `standard_error` that of the best candidate's mean, the tolerance of the choice;
    `extended`: how many times the grid was extended upward because the choice sat on its top;
    `at_top`: the choice is still the largest candidate (the held-out error did not tell a
    smaller lambda apart: very noisy or misregistered input, or `MAX_EXTENSIONS` reached);
    `saturated`: the grid reached `SATURATION` times the crops' largest eigenvalue, above which
    the fit no longer changes."""

    smoothing: float
    relative: float
    grid: tuple[float, ...]
    objective: tuple[float, ...]
    standard_error: float
    crops: int
    crop_points: int
    seconds: float
    extended: int = 0
    at_top: bool = False
    saturated: bool = False
    noise: float = float("nan")
    residual: float | None = None
    lowered_from: tuple[float, float] | None = None

    def summary(self) -> str:
        obj = np.asarray(self.objective)
        best = int(np.argmin(obj))
        kind = (
            "interpolation (no smoothing: "
            + (
                "every smoothing leaves the crops' fits too far from their samples)"
                if self.lowered_from is not None
                else "the held-out error does not improve with it)"
            )
            if self.smoothing == 0
            else f"lambda = {self.relative:.2e} x diagonal^h ({self.smoothing:.3e} in the points' units)"
        )
        chosen = int(np.argmin(np.abs(np.asarray(self.grid) - self.relative)))
        return (
            f"denoise: {kind}; held-out error on {self.crops} crops of {self.crop_points:,} "
            f"points ({self.seconds:.1f} s): {obj[0]:.4f} at lambda 0, minimum {obj[best]:.4f} at "
            f"{self.grid[best]:.1e} (standard error {self.standard_error:.4f}), {obj[chosen]:.4f} "
            + (
                "at the chosen lambda (the largest within one standard error of the minimum)"
                if self.lowered_from is None
                else "at the chosen lambda (below the one-standard-error choice: the noise bounds it)"
            )
            + self._top_note()
            + self._noise_note()
        )

    def _noise_note(self) -> str:
        if self.residual is None:
            return ""
        note = f"; the crops' fits pass a median {self.residual:.2f} noise sigma from their samples"
        if self.lowered_from is not None:
            lam, far = self.lowered_from
            note += (
                f" (lowered from lambda {lam:.1e}, where they passed {far:.2f} sigma from them, "
                f"more than {DISCREPANCY:g}: a surface that removed just the noise lies 0.67 "
                "sigma from them)"
            )
        return note

    def _top_note(self) -> str:
        note = ""
        if self.extended:
            note = (
                f"; the choice sat on the top of the grid, which was extended {self.extended} "
                f"time(s) up to {self.grid[-1]:.1e}"
            )
        if self.at_top:
            note += "; the choice is the top of the grid" + (
                ", where the fit of every crop is its polynomial: the input is too noisy for "
                "the held-out error to prefer any detail"
                if self.saturated
                else " (give a larger grid, or `smoothing` by hand)"
            )
        return note


def _noise_sigma(points, normals) -> float:
    """The noise's sigma across the surface of `points` (`jaxrbf.estimate_noise`)."""
    from ._noise import estimate_noise

    return float(estimate_noise(points, normals).sigma)


def _crops(points, count, size, seed):
    """Index arrays of `count` crops: the `size` nearest neighbours of spread-out seed points."""
    from scipy.spatial import cKDTree

    tree = cKDTree(points)
    rng = np.random.default_rng(seed)
    # Farthest-point seeds from a random start spread the crops over the shape.
    seeds = [int(rng.integers(len(points)))]
    dist = np.linalg.norm(points - points[seeds[0]], axis=1)
    for _ in range(count - 1):
        seeds.append(int(np.argmax(dist)))
        dist = np.minimum(dist, np.linalg.norm(points - points[seeds[-1]], axis=1))
    out = []
    for s in seeds:
        d, idx = tree.query(points[s], k=size, workers=-1)
        inner = np.flatnonzero(d <= INTERIOR * d[-1])
        out.append((idx, inner))
    return out


def choose_smoothing(
    points,
    normals,
    *,
    kernel="cubic",
    offset: float,
    radius: float | None = None,
    degree: int = 1,
    crops: int = CROPS,
    crop_points: int = CROP_POINTS,
    grid=GRID,
    seed: int = 0,
    noise: float | None = None,
    verbose: bool = False,
) -> SmoothingReport:
    """The smoothing lambda of a surface fit of `points` with outward `normals`, chosen by the
    held-out error (`jaxrbf.objectives.held_out_error`) on `crops` crops of `crop_points` points each.

    **Arguments:** `kernel`, `offset` (d), `radius` (kernels with one) and `degree` as the fit
    will use them, in the points' units; `grid`: candidate lambdas in units of diagonal^h;
    `noise`: the noise's sigma across the surface in the points' units (default: estimated,
    `jaxrbf.estimate_noise`), which bounds the choice (see the module's docstring).

    **Returns:** a `SmoothingReport`; its `smoothing` goes to `fit(..., smoothing=...)`.
    """
    from ._prepare import diagonal
    from .kernels import make_kernel

    t0 = time.perf_counter()
    p = np.asarray(points, dtype=float)
    nrm = np.asarray(normals, dtype=float)
    if p.ndim != 2 or nrm.shape != p.shape:
        raise InputError(
            f"`points` and `normals` must be (n, d) arrays of one shape, got {p.shape} and {nrm.shape}"
        )
    grid = tuple(sorted(float(g) for g in grid))
    if not grid or any(not (np.isfinite(g) and g >= 0) for g in grid):
        raise InputError(f"`grid` must hold lambdas >= 0, got {grid}")
    size = min(int(crop_points), len(p))
    if size < 50:
        raise InputError(f"choosing the smoothing needs at least 50 points, got {len(p)}")
    kern = make_kernel(kernel, radius)
    unit = diagonal(p) ** kern.homogeneity
    parts = _crops(p, max(1, int(crops)), size, seed)
    setups = [_Crop(p[idx], nrm[idx], inner, kern, offset, degree, seed) for idx, inner in parts]
    # (held-out points, candidates), the crops' held-out points pooled
    per_point = np.concatenate([c.errors(np.asarray(grid) * unit) for c in setups], axis=0)
    if not np.isfinite(per_point.mean(axis=0)).any():
        raise InputError(
            "choosing the smoothing: every candidate fit failed on the crops (singular systems); "
            "check the points for duplicates, or give `smoothing` by hand"
        )
    # Past this, every crop's fit is its polynomial plus a vanishing kernel part: larger lambdas
    # only scale that part down further, so the grid is never extended beyond it.
    ceiling = SATURATION * max(c.largest() for c in setups) / unit
    extended = 0
    while True:
        scores = per_point.mean(axis=0)
        best = int(np.argmin(scores))  # failed candidates score inf, never NaN
        se = float(np.std(per_point[:, best], ddof=1) / np.sqrt(len(per_point)))
        chosen = best
        while chosen + 1 < len(grid) and scores[chosen + 1] <= scores[best] + se:
            chosen += 1
        top = grid[-1]
        if chosen < len(grid) - 1 or extended >= MAX_EXTENSIONS or not 0 < top < ceiling:
            break
        # The choice sits on the top of the grid: more quarter decades above it, from the same
        # eigendecompositions.
        more = tuple(top * 10.0 ** ((i + 1) / 4) for i in range(EXTENSION))
        per_point = np.concatenate(
            [per_point, np.concatenate([c.errors(np.asarray(more) * unit) for c in setups])],
            axis=1,
        )
        grid = grid + more
        extended += 1
    sigma = float(noise) if noise is not None else _noise_sigma(p, nrm)
    lowered, residual = None, None
    if chosen > 0 and np.isfinite(sigma) and sigma > 0:
        cap = DISCREPANCY * sigma
        med = np.median(
            np.concatenate([c.residuals(np.asarray(grid[: chosen + 1]) * unit) for c in setups]),
            axis=0,
        )
        if med[chosen] > cap:
            sound = np.isfinite(np.asarray(scores[: chosen + 1])) & np.isfinite(med)
            within = np.flatnonzero(sound & (med <= cap))
            lowered = (grid[chosen], float(med[chosen] / sigma))
            chosen = int(within[-1]) if len(within) else int(np.flatnonzero(sound)[0])
        residual = float(med[chosen] / sigma)
    rel = grid[chosen]
    report = SmoothingReport(
        smoothing=rel * unit,
        relative=rel,
        grid=grid,
        objective=tuple(float(s) for s in scores),
        standard_error=se,
        crops=len(parts),
        crop_points=size,
        seconds=time.perf_counter() - t0,
        extended=extended,
        at_top=chosen == len(grid) - 1 and len(grid) > 1,
        saturated=grid[-1] >= ceiling,
        noise=sigma,
        residual=residual,
        lowered_from=lowered,
    )
    if verbose:
        log(report.summary())
    return report


def _crop_errors(pc, nc, inner, kern, offset, degree, lams, seed):
    """Held-out errors (points, candidates) of one crop: fit on all but a third of its interior
    points (`inner`), measure `surface_error`'s two terms at those, for every lambda in `lams`
    (the points' units) at once; inf rows where a candidate failed."""
    return _Crop(pc, nc, inner, kern, offset, degree, seed).errors(lams)


class _Crop:
    """One crop's fit setup and the eigendecomposition of its system (see the module's
    docstring), kept so that further lambdas (an extension of the grid) cost no new O(n^3) step."""

    def __init__(self, pc, nc, inner, kern, offset, degree, seed):
        from ._difffit import unit_box
        from .objectives import capped_constraints, point_spacing

        test = np.sort(
            np.random.default_rng(seed).choice(inner, max(1, len(inner) // 3), replace=False)
        )
        train = np.setdiff1d(np.arange(len(pc)), test)
        pt, nt = pc[train], nc[train]
        c = capped_constraints(pt, nt, offset)
        x, h = np.asarray(c.points), np.asarray(c.values)
        shift, scale = (np.asarray(v) for v in unit_box(jnp.asarray(x)))
        n = len(x)
        m = -(-n // PAD) * PAD
        xn = np.zeros((m, x.shape[1]))
        xn[:n] = (x - shift) / scale
        hp = np.zeros(m)
        hp[:n] = h
        self.scale, self.homogeneity, self.degree = float(scale), kern.homogeneity, degree
        self.kern = kern.scaled(1.0 / scale)
        self.xn = jnp.asarray(xn)
        self.tp = jnp.asarray((pc[test] - shift) / scale)
        self.tn = jnp.asarray(nc[test])
        self.own = jnp.asarray((pt - shift) / scale)  # the fitted samples
        self.length = jnp.asarray(point_spacing(pc) / scale)
        self.spectrum = _spectrum(
            self.kern, self.xn, jnp.asarray(hp), jnp.asarray(np.arange(m) < n), degree
        )

    def largest(self) -> float:
        """The largest eigenvalue of the crop's system, in the points' units: far above it the
        fit no longer depends on lambda's size beyond a factor (it is the crop's polynomial)."""
        return float(jnp.max(self.spectrum[0])) * self.scale**self.homogeneity

    def _unit(self, lams) -> jax.Array:
        """Lambdas in the points' units, in the crop's unit box."""
        return jnp.asarray(np.asarray(lams, dtype=float) / self.scale**self.homogeneity)

    def errors(self, lams) -> np.ndarray:
        err = _path_errors(
            self.kern,
            self.xn,
            self.spectrum,
            self._unit(lams),
            self.tp,
            self.tn,
            self.length,
            self.degree,
        )
        return np.asarray(err)

    def residuals(self, lams) -> np.ndarray:
        """(fitted samples, candidates) distances from the samples to the fits, in the points'
        units (inf where a candidate failed)."""
        dist = _path_residuals(
            self.kern, self.xn, self.spectrum, self._unit(lams), self.own, self.degree
        )
        return np.asarray(dist) * self.scale


@eqx.filter_jit
def _spectrum(kern, xn, h, mask, degree: int):
    """The eigendecomposition V L V^T of C = Pi A Pi + Q1 Q1^T of constraints `xn` (padded; `mask`
    marks the real ones), the projected values Pi h, and what the polynomial part needs:
    (L, V, Pi h, Q1, R, Q1^T A, Q1^T h)."""
    from ._model import kernel_block, poly_basis
    from ._solve import _null_space_matrix, _projector

    real = mask[:, None] & mask[None, :]
    a = jnp.where(real, kernel_block(kern, xn, xn), 0.0)
    p = poly_basis(xn, degree) * mask[:, None]
    k = p.shape[1]
    if k:
        q1, r = _projector(p)
        qa, qh = q1.T @ a, q1.T @ h
        c_mat = _null_space_matrix(a, q1)
        ph = h - q1 @ qh
    else:
        q1, r = jnp.zeros((xn.shape[0], 0)), jnp.zeros((0, 0))
        qa, qh = jnp.zeros((0, xn.shape[0])), jnp.zeros((0,))
        c_mat, ph = a, h
    # Padded rows and columns: an identity block, decoupled from the real system (zero right
    # side, so zero weights there).
    c_mat = c_mat + jnp.diag(jnp.where(mask, 0.0, 1.0))
    evals, vecs = jnp.linalg.eigh(c_mat)
    return evals, vecs, ph, q1, r, qa, qh


def _path_fits(kern, xn, spectrum, lams, degree: int):
    """The fits of every smoothing in `lams` from the crop's `_spectrum`: a function of points
    (t, d) -> values (t, lambdas), and which candidates are sound (shifted eigenvalues > 0)."""
    from ._model import kernel_block, poly_basis

    evals, vecs, ph, q1, r, qa, qh = spectrum
    shifted = evals[:, None] + lams[None, :]
    ok = jnp.all(shifted > 1e-14 * jnp.max(jnp.abs(evals)), axis=0)
    w = vecs @ ((vecs.T @ ph)[:, None] / shifted)  # (m, lambdas)
    if q1.shape[1]:
        # P c = h - (A + lambda I) w, solved through P = Q1 R.
        rhs = qh[:, None] - qa @ w - lams[None, :] * (q1.T @ w)
        coef = jax.scipy.linalg.solve_triangular(r, rhs, lower=False)
    else:
        coef = jnp.zeros((0, lams.shape[0]), dtype=ph.dtype)

    def values(x):
        return kernel_block(kern, x, xn) @ w + poly_basis(x, degree) @ coef  # (t, lambdas)

    return values, ok


@eqx.filter_jit
def _path_residuals(kern, xn, spectrum, lams, x, degree: int):
    """(points, lambdas) first-order distances |f| / |grad f| from the crop's own samples `x` to
    the fits of every smoothing in `lams` (inf where a candidate failed)."""
    from ._model import forward_value_and_gradient
    from .objectives import first_order_distance

    values, ok = _path_fits(kern, xn, spectrum, lams, degree)
    t, d = x.shape
    f, g = forward_value_and_gradient(values, x)  # flattened over (t, lambdas)
    dist = first_order_distance(f.reshape(t, -1), g.reshape(t, -1, d))
    return jnp.where(ok[None, :], dist, jnp.inf)


@eqx.filter_jit
def _path_errors(kern, xn, spectrum, lams, tp, tn, length, degree: int):
    """(test points, lambdas) held-out errors |f| / |grad f| / length + max(0, 1 - cos(grad f, n))
    of the fits with every smoothing in `lams`, from the crop's `_spectrum`."""
    from ._model import forward_value_and_gradient
    from .objectives import pointwise_errors

    values, ok = _path_fits(kern, xn, spectrum, lams, degree)
    t, d = tp.shape
    f, g = forward_value_and_gradient(values, tp)  # flattened over (t, lambdas)
    dist, mis = pointwise_errors(f.reshape(t, -1), g.reshape(t, -1, d), tn[:, None, :], length)
    err = dist + mis
    return jnp.where(ok[None, :] & jnp.all(jnp.isfinite(err), axis=0)[None, :], err, jnp.inf)
