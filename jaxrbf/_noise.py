"""`estimate_noise`: how far a point cloud scatters across its own surface.

An interpolating fit reproduces every sample exactly, so scatter across the surface (a scanner's
noise, or overlapping range scans registered a fraction of a spacing apart) becomes bumps of the
size of the point spacing. This module measures that scatter from the points alone, so that a
caller can decide whether the fit should approximate (`choose_smoothing`).

The statistic, per point: its k nearest neighbours (the point included), a local frame from their
covariance (the height axis along its smallest eigenvector, or along the given normal), and the
least-squares quadric height field h(u, v) = a + b u + c v + d u^2 + e uv + f v^2 over the tangent
coordinates (a parabola h(u) in 2-D); with normals, a neighbourhood that reaches points facing
the other way (the other face of a part a few spacings thin) is fitted again on the point's own
face, and the smaller residual kept. Its residual RMS with nu = k + 1 - 6 degrees of freedom,
sqrt(SSR / nu), estimates the noise's standard deviation across the surface: the quadric absorbs
curvature, which a plane's residual would count as noise. It cannot absorb a sharp crease, both
sides of a thin part or a coarse mesh's facet kinks; those only ever raise a point's residual,
while noise raises every point's. So the cloud's sigma is a low quantile (`QUANTILE`) of the
per-point estimates, divided by that quantile of sqrt(chi^2_nu / nu) so that it is sigma for
Gaussian noise. (For two sheets a distance t apart, it reads up to ~1.7 t / 2: a residual that is
nearly constant has a heavier low quantile than a Gaussian's.)

Noise comparable with the neighbourhood (dense samples: at 1M points 0.1% of the diagonal is
~2 spacings) hides in it, the quadric follows it and sigma comes out low; the estimate is then
repeated on random subsets thinned 4x at a time, whose k neighbours reach twice as far, until
sigma is below `WIDE` times their reach.

`noisy` compares sigma with the median nearest-neighbour spacing: the roughness an interpolant
shows is the noise relative to the spacing (bumps of height sigma a spacing wide). The threshold,
`NOISY_SPACING`, was measured on several meshes, densities, noise levels and simulated
misregistered scans (see its comment).

Host work: KD-tree queries and batched 6 x 6 solves in numpy, on at most `SAMPLE` points; about
1 s at 100,000 points and 2-4 s at 1M on the 2-core reference machine.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ._errors import InputError

#: Neighbours per local fit (the point itself not counted): few, so that a neighbourhood rarely
#: reaches a crease, a facet's kink or the other side of a thin part (measured: k = 12 against
#: 16 and 20, the quantile below against the median, on the meshes of `NOISY_SPACING`).
NOISE_K = 12
#: The cloud's sigma is this quantile of the per-point estimates (scaled to be unbiased for
#: Gaussian noise): the neighbourhoods that geometry spoils (creases, thin parts, a coarse mesh's
#: facet kinks) have larger residuals, never smaller, so a low quantile ignores them even where
#: they are most of the points (a low-poly mesh sampled densely), as noise raises every one.
QUANTILE = 0.25
#: Per-point fits on at most this many points (a random subset; neighbours from all points).
SAMPLE = 50_000
#: Neighbours per batch of local fits (bounds the (batch, k, 6) design arrays to ~100 MB).
BUDGET = 2_000_000
#: Neighbourhoods are widened while sigma exceeds this fraction of their reach: noise that large
#: makes the quadric follow it, and sigma comes out low (measured on the meshes of
#: `NOISY_SPACING` at 100,000 points: 0.77x the true sigma at 0.5% noise, sigma ~ 0.45 reach;
#: 0.5x at 0.9 reach). They are widened by thinning: the same k neighbours in a random 1 in 4
#: subset reach twice as far, at the cost of one pass over that subset, ...
WIDE = 0.25
#: ... down to subsets of this many points at least, fitting at most `WIDE_SAMPLE` of them.
WIDE_MIN_POINTS = 2000
WIDE_SAMPLE = 20_000
#: `noisy` when the estimated sigma exceeds this fraction of the median nearest-neighbour spacing.
#: Measured (k = 12, `QUANTILE`) on uniform samples (`jaxrbf.metrics.sample_surface`) of seven
#: shared meshes (stanford-bunny, spot, fandisk, cow, teapot, suzanne, beetle-alt) at 10,000 and
#: 100,000 points: clean samples give 0.000-0.047 (the most: the cow, the bunny and suzanne at
#: 10,000 points, where thin parts, fine detail and facet kinks span few spacings); Gaussian
#: noise of 0.1% of the diagonal (per coordinate) 0.21 and more, 0.25% 0.44, 0.5% 0.68;
#: simulated misregistered scans (six overlapping views of the mesh, each shifted by 0.3
#: spacings in a random direction, so its sheet sits ~0.15 spacings from its neighbours') 0.065
#: and more, 0.6 spacings 0.082 and more. 0.055 sits between the clean and the misregistered.
#: Real scans in ../shared/data: scanned-leg 0.14, anchor 0.41 (both noisy). Below ~10,000
#: points detail becomes sub-spacing and reads as noise (clean at 4,000: up to 0.084, suzanne;
#: at 2,000: 0.135): a false "noisy" there costs a `choose_smoothing` that keeps lambda small.
NOISY_SPACING = 0.055


@dataclass(frozen=True)
class NoiseReport:
    """What `estimate_noise` measured.

    - `sigma`: the noise across the surface (standard deviation, in the points' units), from
      the `QUANTILE` of the per-point estimates.
    - `spacing`: the median nearest-neighbour distance; `diagonal`: the bounding-box diagonal.
    - `relative_spacing` = sigma / spacing, `relative_diagonal` = sigma / diagonal.
    - `noisy`: `relative_spacing` > `threshold` (`NOISY_SPACING`; with the first, narrow
      neighbourhoods or the widened ones): an interpolant would show the noise; smooth instead.
    - `rough_fraction`: the fraction of the points whose own estimate exceeds the threshold
      (a noisy region, or creases and thin parts, which a clean cloud also has).
    - `n` points, `sampled` of them fitted, `k` neighbours; `thinned` > 1 when the noise was
      too large for those neighbourhoods and sigma comes from wider ones: the k neighbours in a
      random subset of 1 in `thinned` points; `seconds`.
    """

    sigma: float
    spacing: float
    diagonal: float
    relative_spacing: float
    relative_diagonal: float
    noisy: bool
    threshold: float
    rough_fraction: float
    n: int
    sampled: int
    k: int
    thinned: int
    seconds: float

    def summary(self) -> str:
        verdict = (
            "noisy: an interpolant would follow it, so the fit should smooth"
            if self.noisy
            else "clean enough to interpolate"
        )
        wide = f", then in a 1-in-{self.thinned} subset" if self.thinned > 1 else ""
        return (
            f"noise: sigma {self.relative_diagonal:.3%} of the diagonal, "
            f"{self.relative_spacing:.3f} point spacings (threshold {self.threshold:g}; quadric "
            f"fits of {self.k} neighbours at {self.sampled:,} of {self.n:,} points{wide}, "
            f"{self.seconds:.1f} s): {verdict}"
        )


def _local_sigma(nb: np.ndarray, axis: np.ndarray | None) -> np.ndarray:
    """Residual RMS (dof-corrected) of the quadric height fits of neighbourhoods `nb` (b, k, d),
    and each neighbourhood's reach (largest tangent distance from its centre); `axis` (b, d) the
    height axes, or None for the smallest principal axis of each."""
    b, kk, d = nb.shape
    centre = nb.mean(axis=1)
    x = nb - centre[:, None, :]
    cov = np.matmul(x.transpose(0, 2, 1), x)
    _, vec = np.linalg.eigh(cov)  # ascending: vec[..., 0] is across the surface
    if axis is None:
        frame = vec
    elif d == 3:
        # Height along the given normal; tangent axes: the main principal axis made orthogonal
        # to it, and their cross product.
        e = vec[:, :, -1]
        t1 = e - axis * np.sum(axis * e, axis=1, keepdims=True)
        t1 /= np.maximum(np.linalg.norm(t1, axis=1, keepdims=True), 1e-300)
        frame = np.stack([axis, np.cross(axis, t1), t1], axis=2)
    else:
        frame = np.stack([axis, np.stack([-axis[:, 1], axis[:, 0]], axis=1)], axis=2)
    local = np.matmul(x, frame)  # column 0: height
    h = local[:, :, 0]
    uv = local[:, :, 1:]
    reach = np.sqrt(np.maximum(np.max(np.sum(uv * uv, axis=2), axis=1), 1e-300))
    uv = uv / reach[:, None, None]
    one = np.ones((b, kk, 1))
    if d == 3:
        u, v = uv[:, :, :1], uv[:, :, 1:]
        design = np.concatenate([one, u, v, u * u, u * v, v * v], axis=2)
    else:
        u = uv[:, :, :1]
        design = np.concatenate([one, u, u * u], axis=2)
    m = design.shape[2]
    dt = design.transpose(0, 2, 1)
    gram = np.matmul(dt, design)
    rhs = np.matmul(dt, h[:, :, None])
    # A tiny ridge keeps degenerate neighbourhoods (collinear points) solvable.
    gram = gram + 1e-10 * np.eye(m) * np.trace(gram, axis1=1, axis2=2)[:, None, None]
    coef = np.linalg.solve(gram, rhs)
    res = h - np.matmul(design, coef)[:, :, 0]
    return np.sqrt(np.sum(res * res, axis=1) / (kk - m)), reach


def _pass(p, nrm, tree, at, k):
    """Per-point sigmas and reaches of the quadric fits of the `k` neighbours of points `at`, and
    their nearest-neighbour distances."""
    sig, reach, nearest = (np.empty(len(at)) for _ in range(3))
    # With normals, a neighbourhood that reaches the other face of a part thinner than a few
    # spacings (or of a doubled sheet) reads noise of half its thickness everywhere on it: there
    # the point's own sheet is fitted too, the nearest k facing its way among 2k + 1, and the
    # smaller residual is kept. Noise raises both; where the faces are only flipped at random,
    # the own sheet is half as dense and the first fit the fairer one.
    wide = k + 1 if nrm is None else min(2 * k + 1, len(p))
    step = max(1, BUDGET // wide)
    for s in range(0, len(at), step):
        q = at[s : s + step]
        dist, idx = tree.query(p[q], k=wide, workers=-1)
        nearest[s : s + len(q)] = dist[:, 1]
        near = idx[:, : k + 1]
        sg, rc = _local_sigma(p[near], None if nrm is None else nrm[q])
        if nrm is not None:
            facing = np.einsum("bkd,bd->bk", nrm[idx], nrm[q]) > 0
            mixed = np.flatnonzero(~np.all(facing[:, : k + 1], axis=1))
            if len(mixed):
                order = np.argsort(~facing[mixed], axis=1, kind="stable")[:, : k + 1]
                own = np.take_along_axis(idx[mixed], order, axis=1)
                sg2, rc2 = _local_sigma(p[own], nrm[q[mixed]])
                better = sg2 < sg[mixed]
                sg[mixed[better]], rc[mixed[better]] = sg2[better], rc2[better]
        sig[s : s + len(q)], reach[s : s + len(q)] = sg, rc
    return sig, reach, nearest


def _chi2_ratio(q: float, k: int, d: int) -> float:
    """The q-quantile of chi^2_nu / nu, nu = the residual's degrees of freedom of a quadric fit
    of k + 1 points in d dimensions."""
    from scipy.special import gammaincinv  # chi2.ppf without importing scipy.stats (seconds)

    nu = k + 1 - (6 if d == 3 else 3)
    return float(2 * gammaincinv(nu / 2, q) / nu)


def _sigma(sig: np.ndarray, k: int, d: int) -> float:
    """The cloud's sigma from per-point estimates: their `QUANTILE`, over its value for Gaussian
    noise (SSR / sigma^2 is chi^2 with nu degrees of freedom)."""
    return float(np.quantile(sig, QUANTILE)) / np.sqrt(_chi2_ratio(QUANTILE, k, d))


def estimate_noise(
    points,
    normals=None,
    k: int = NOISE_K,
    *,
    sample: int | None = SAMPLE,
    threshold: float = NOISY_SPACING,
    seed: int = 0,
) -> NoiseReport:
    """The scatter of `points` across their surface: a robust estimate of the noise's standard
    deviation, relative to the point spacing and to the diagonal (see the module docstring).

    **Arguments:**
    - `points`: (n, d) points, d = 2 or 3; `normals`: (n, d) or None. Given normals set each
      local fit's height axis and keep each fit to the neighbours that face the point's way
      (its own sheet, not the other face of a thin part); without them the height axis is the
      smallest principal axis of the neighbourhood.
    - `k`: neighbours per local quadric fit (at least 8 in 3-D, 5 in 2-D).
    - `sample`: fit at most this many points, chosen at random (None: all of them).
    - `threshold`: `noisy` when sigma exceeds this many median point spacings.
    - `seed`: seed of the random subset.

    **Returns:** a `NoiseReport`.
    """
    from scipy.spatial import cKDTree

    from ._prepare import diagonal
    from .io import as_points

    t0 = time.perf_counter()
    p = as_points(points, "points")
    n, d = p.shape
    nrm = None
    if normals is not None:
        nrm = np.asarray(normals, dtype=float)
        if nrm.shape != p.shape:
            raise InputError(
                f"`normals` must have the shape of `points` {p.shape}, got {nrm.shape}"
            )
        length = np.linalg.norm(nrm, axis=1)
        if not np.all(np.isfinite(length) & (length > 0)):
            raise InputError("`normals` must be finite and non-zero")
        nrm = nrm / length[:, None]
    k = int(k)
    k_min = 8 if d == 3 else 5
    if k < k_min:
        raise InputError(f"`k` must be at least {k_min} for a {d}-D quadric fit, got {k}")
    if n < k + 1:
        raise InputError(
            f"estimating the noise with k = {k} needs at least {k + 1} points, got {n:,}"
        )
    if not (np.isfinite(threshold) and threshold > 0):
        raise InputError(f"`threshold` must be a positive number, got {threshold!r}")
    diag = diagonal(p)
    if not diag > 0:
        raise InputError("all points coincide: there is no surface to measure the noise of")
    rng = np.random.default_rng(seed)
    if sample is not None and n > int(sample):
        at = np.sort(rng.choice(n, int(sample), replace=False))
    else:
        at = np.arange(n)
    tree = cKDTree(p)
    sig, reach, nearest = _pass(p, nrm, tree, at, k)
    spacing = float(np.median(nearest))
    if not spacing > 0:
        raise InputError(
            "more than half of the points have a duplicate: merge them before estimating the noise"
        )
    first = _sigma(sig, k, d)
    sigma = first
    per_point = sig / np.sqrt(_chi2_ratio(0.5, k, d))  # median-unbiased, point by point
    rough = float(np.mean(per_point > threshold * spacing))
    # Noise comparable with the neighbourhood's size hides in it (the quadric follows it, and the
    # frame tilts): widen the neighbourhoods, on fewer points, until it is small beside them.
    thinned = 1
    while sigma > WIDE * float(np.median(reach)) and n // (4 * thinned) >= WIDE_MIN_POINTS:
        thinned *= 4
        sub = np.sort(rng.choice(n, n // thinned, replace=False))
        ps = p[sub]
        few = np.arange(len(sub))
        if len(sub) > WIDE_SAMPLE:
            few = np.sort(rng.choice(len(sub), WIDE_SAMPLE, replace=False))
        sig_w, reach, _ = _pass(ps, None if nrm is None else nrm[sub], cKDTree(ps), few, k)
        sigma = _sigma(sig_w, k, d)
    rel = sigma / spacing
    return NoiseReport(
        sigma=float(sigma),
        spacing=spacing,
        diagonal=diag,
        relative_spacing=float(rel),
        relative_diagonal=float(sigma / diag),
        noisy=bool(max(sigma, first) > threshold * spacing),
        threshold=float(threshold),
        rough_fraction=rough,
        n=n,
        sampled=len(at),
        k=k,
        thinned=thinned,
        seconds=time.perf_counter() - t0,
    )
