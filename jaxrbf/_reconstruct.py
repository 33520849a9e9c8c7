"""One-shot helpers: a file or arrays in, a model or a mesh out. The CLI is a thin shell over these.

Here `offset` and `radius` are fractions of the input's bounding-box diagonal (as on the command
line), so the defaults do not depend on the input's units. The building blocks (`Constraints`,
`fit`) take them in the input's own units.
"""

from __future__ import annotations

import os
import time

import numpy as np

from ._constraints import DEFAULT_OFFSET, Constraints, log
from ._errors import InputError
from ._fit import choose_method, fit
from ._model import AbstractModel, n_poly
from ._prepare import (
    auto_flag,
    check_not_flat,
    consistent_winding,
    diagonal,
    merged_duplicates,
)
from .objectives import point_spacing

#: Surface points of a point cloud for the dense method: 4,000 points give 12,004 unknowns, a
#: dense solve of ~15 s on a 2-core CPU (`subsample`).
DEFAULT_POINTS = 4000
#: Surface samples of a mesh by default: as many as it has vertices (the detail it was made with),
#: at least MESH_MIN_POINTS (a low-poly model's large faces, a many-piece model's small pieces)
#: and at most MESH_MAX_POINTS. Measured on the beetle given as its .obj (1,148 vertices, 33 open
#: pieces): 1,148 samples gave Chamfer-L1 0.248% / NC 0.932 / precision 83.9%, 10,000 give
#: 0.113% / 0.967 / 99.5% (4,000 samples, the default before, were also fewer than the bunny's
#: 35,947 vertices and lost its detail).
MESH_MIN_POINTS = 10_000
MESH_MAX_POINTS = 100_000
EXAMPLES = ("bunny",)
#: With the partition method, the default offset is at most this many median point spacings.
PARTITION_OFFSET_SPACINGS = 2.0


#: From this many surface samples on, a 3-D partition of unity defaults to the linear kernel.
LINEAR_FROM = 50_000


def default_kernel(dim: int, method: str, n_samples: int, exact: bool = False) -> str:
    """`fit_surface`'s kernel when none is named: the paper's cubic r^3 in 3-D (thin-plate
    r^2 log r in 2-D), except for a 3-D partition of unity of at least `LINEAR_FROM` samples, or
    of any size when it interpolates samples whose normals came with the input (`exact`: a
    mesh's face normals, a clean cloud's given normals), which gets the linear r (the 3-D
    biharmonic spline of Carr et al. 2001). Measured (Chamfer-L1 / normal consistency against
    the original mesh):

    - 100k samples with true normals, meshed at R = 256: the fandisk 0.0526% / 0.9916 with r^3,
      whose fit ripples a few point spacings beside the sharp creases, against 0.0525% / 0.9924
      with r; the bunny 0.0563% / 0.9933 against 0.0563% / 0.9934;
    - 10k samples with true normals (`benchmarks/wild.py`, default command; Chamfer / NC /
      precision at 0.5%, r^3 at 60af37b against r at c2c11a7): the same ripples beside creases
      and where pieces meet: the teapot 0.1230% / 0.9715 / 98.66% against 0.1234% / 0.9736 /
      99.11%, suzanne (low-poly: every edge a crease) 0.1385% / 0.9452 / 98.64% against
      0.1374% / 0.9523 / 99.23%, the beetle soup NC 0.848 against 0.851; the smooth bunny is
      the exception, 0.1201% / 0.9897 / 98.71% against 0.1219% / 0.9893 / 98.69% (Poisson
      depth 9 on the same points: 0.1298% / 0.9855 / 98.65-98.72% in two runs);
    - 20k raw samples (estimated normals, `denoise`, R = 192; `benchmarks/raw_scans.py`): r^3
      is the better one, e.g. the fandisk 0.1201% / 0.9857 against 0.1208% / 0.9849 without
      noise and the spot 0.1748% / 0.9675 against 0.1837% / 0.9624 at 0.5% noise (the bunny at
      0.5% noise is the exception: 0.2217% / 0.9441 against 0.2096% / 0.9511): estimated
      normals turn smoothly across a crease, so there is no crease in them for r to keep.
    """
    if dim != 3:
        return "thin-plate"
    if method == "partition" and (exact or n_samples >= LINEAR_FROM):
        return "linear"
    return "cubic"


def partition_offset(surface: np.ndarray) -> float:
    """`PARTITION_OFFSET_SPACINGS` median nearest-neighbour spacings of `surface`, as a fraction of
    its diagonal."""
    return PARTITION_OFFSET_SPACINGS * point_spacing(surface) / diagonal(surface)


def example(name: str = "bunny") -> tuple[np.ndarray, np.ndarray]:
    """The bundled example: `(points, normals)` sampled on the Stanford bunny (see
    `jaxrbf/data/README.md` for its source and attribution)."""
    from importlib.resources import files

    if name not in EXAMPLES:
        raise InputError(f"unknown example {name!r}; expected one of {', '.join(EXAMPLES)}")
    with files("jaxrbf").joinpath("data", f"{name}.npz").open("rb") as fh, np.load(fh) as z:
        return np.asarray(z["points"], dtype=float), np.asarray(z["normals"], dtype=float)


def _subsample(p, n, k, seed):
    if k is None:
        k = len(p)
    if k < len(p):
        idx = np.sort(np.random.default_rng(seed).choice(len(p), k, replace=False))
        return p[idx], n[idx]
    return p, n


NORMALS = ("auto", "given", "estimate")


def _normals_mode(normals):
    """`(mode, array or None)` from the `normals` argument (an array, None or a mode name)."""
    if normals is None:
        return "auto", None
    if isinstance(normals, str):
        if normals not in NORMALS:
            raise InputError(
                f"unknown `normals` {normals!r}; expected an (n, d) array or one of "
                f"{', '.join(NORMALS)}"
            )
        return normals, None
    return "given", normals


def _clean_cloud(data, name: str, mode: str, outliers: bool, verbose: bool):
    """The point cloud `data` after outlier removal and with normals as `mode` asks."""
    from . import io

    p, n = data.points, data.normals
    if mode == "given" and n is None:
        raise InputError(
            f"{name} has points but no normals; give nx, ny, nz columns (or a mesh) so that "
            "inside and outside are known, or estimate them (--normals estimate|auto)"
        )
    if outliers:
        from ._clean import remove_outliers

        p, n, rep = remove_outliers(p, n)
        if verbose:
            log(f"{name}: {rep.summary()}")
    if mode == "estimate" or n is None:
        if p.shape[1] != 3:
            raise InputError(
                f"{name} has 2-D points without normals; normal estimation is 3-D only: give "
                "normals or a polyline (.csv .npy)"
            )
        from ._normals import estimate_normals

        why = "estimating them" if n is None else "re-estimating them (--normals estimate)"
        log(f"{name}: {'no normals given' if n is None else 'normals given'}, {why}")
        n, rep = estimate_normals(p)
        log(rep.summary())
    return io.PointCloud(p, n)


def surface_from(source, normals=None, **options) -> tuple[np.ndarray, np.ndarray, float]:
    """The surface samples of `source` with outward normals: `(points, normals, diagonal)`, the
    diagonal being that of the input (the unit of `offset` and `radius` fractions). Arguments as
    for `constraints_from`. Host."""
    return _surface(source, normals, **options)[:3]


def _surface(
    source,
    normals=None,
    *,
    points: int | None = None,
    sampling: str = "faces",
    seed: int = 0,
    subsample: bool = False,
    remove_outliers=False,
    verbose: bool = False,
):
    """`surface_from`, whether the input is a noisy point cloud (`jaxrbf.estimate_noise`;
    False for meshes and polylines, None when `remove_outliers` was not "auto", which is the
    only case that measures it) and whether its normals came with it (a mesh's or polyline's,
    a cloud's own; False where they were estimated): `(points, normals, diagonal, noisy,
    given)`."""
    from . import io
    from ._constraints import mesh_samples, polyline_samples

    if points is not None and int(points) < 1:
        raise InputError(f"`points` must be a positive number, got {points}")
    mode, normals = _normals_mode(normals)
    if isinstance(source, (str, os.PathLike)):
        if normals is not None:
            raise InputError(
                "`normals` as an array goes with an array of points; with a file give "
                "'auto', 'given' or 'estimate'"
            )
        data = io.read_input(source)
        name = os.fspath(source)
    else:
        data = io.PointCloud(
            io.as_points(source, "points"),
            None if normals is None else np.asarray(normals, dtype=float),
        )
        name = "the points"
    if isinstance(data, io.Mesh):
        v, f = data.vertices, data.faces
        check_not_flat(v, f"vertices of {name}")
        f, turned = consistent_winding(v, f)
        if verbose and turned:
            log(
                f"{name}: {turned:,} of {len(f):,} faces were wound against their neighbours; "
                "turned so that each connected piece is wound one way"
            )
        k = points
        if k is None:
            k = min(max(len(v), MESH_MIN_POINTS), MESH_MAX_POINTS)
            if subsample:
                k = min(k, DEFAULT_POINTS)
            if verbose:
                log(f"{name}: {k:,} surface samples of its {len(v):,} vertices (set --points)")
        p, n = mesh_samples(v, f, points=k, sampling=sampling, seed=seed)
        return p, n, diagonal(v), False, True
    if isinstance(data, io.Polyline):
        p, n = polyline_samples(data.vertices, data.closed)
        return p, n, diagonal(data.vertices), False, True
    noisy = None
    given = data.normals is not None and mode != "estimate"
    merged_already = given and data.points.shape[1] == 3
    if merged_already:
        from ._constraints import MERGE_TOL, checked_samples

        p, n = checked_samples(data.points, data.normals)
        check_not_flat(p, f"points of {name}")  # before any merging is said
        p, n, merged, dropped = merged_duplicates(p, n, MERGE_TOL * diagonal(p))
        if merged or dropped:
            log(
                f"{name}: {merged + dropped:,} repeated points (a mesh's vertices exported once "
                f"per face): {merged:,} merged into the first of each, their normals averaged"
                + (f"; {dropped:,} dropped where the copies face opposite ways" if dropped else "")
            )
            data = io.PointCloud(p, n)
    elif data.normals is None or mode == "estimate":
        # A bare cloud (or one whose normals are re-estimated) with repeated positions (scans
        # merged where they overlap, a file written out twice): each kept once, before anything
        # counts neighbours (the noise estimate, outlier removal, normal estimation and the
        # winding number's areas and rims all read a repeated point as a neighbour at distance
        # zero; at 2,000 points of a sphere with 600 repeated, the closed sphere read as full of
        # holes: 7,239 probes over holes and 15,834 closing samples)
        from ._constraints import MERGE_TOL
        from ._prepare import find_duplicates

        check_not_flat(data.points, f"points of {name}")  # before any merging is said
        repeated = find_duplicates(data.points, MERGE_TOL * diagonal(data.points))
        if repeated.any():
            log(
                f"{name}: {int(repeated.sum()):,} repeated points (the same position as an "
                "earlier point): each position kept once"
            )
            keep = ~repeated
            data = io.PointCloud(
                data.points[keep], None if data.normals is None else data.normals[keep]
            )
    if isinstance(remove_outliers, str) and remove_outliers == "auto":
        # A scan as it comes: strays and noise are dealt with without asking. A bare cloud
        # always loses its strays (they mislead the normal estimation); one with normals only
        # when it is noisy.
        noisy = _is_noisy(data, name, verbose, checked=merged_already)
        remove_outliers = noisy or data.normals is None
        if not remove_outliers and len(data.points) > 16:
            # a clean cloud with normals keeps its sparse stretches but not its strays: points
            # far apart from the surface their neighbours sample (each of which would grow a
            # blob of its own), by a local test
            from ._clean import ISOLATED_RATIO, isolated

            apart = isolated(data.points)
            if apart.any():
                data = io.PointCloud(data.points[~apart], data.normals[~apart])
                if verbose:
                    log(
                        f"{name}: removed {int(apart.sum()):,} stray points of "
                        f"{len(apart):,} (mean distance to their 16 nearest more than "
                        f"{ISOLATED_RATIO:g}x their neighbours')"
                    )
    data = _clean_cloud(
        data, name, mode, auto_flag(remove_outliers, "remove_outliers", False), verbose
    )
    check_not_flat(data.points, f"points of {name}")
    if points is None and subsample and len(data.points) > DEFAULT_POINTS:
        points = DEFAULT_POINTS
        if verbose:
            log(
                f"{name}: using {DEFAULT_POINTS:,} of {len(data.points):,} points for the "
                "dense method (set --points, or --method auto|partition for all)"
            )
    p, n = _subsample(data.points, data.normals, points, seed)
    return p, n, diagonal(p), noisy, given


#: Clouds of fewer points get a higher noise threshold (see `_is_noisy`).
SPARSE = 10_000


def _is_noisy(data, name: str, verbose: bool, checked: bool = False) -> bool:
    """Whether the point cloud `data` scatters across its surface (`jaxrbf.estimate_noise`);
    `checked`: its normals were checked and its repeated points merged already."""
    from ._constraints import MERGE_TOL, checked_samples, duplicate_pairs_checked
    from ._noise import NOISY_SPACING, estimate_noise

    # the checks a fit makes anyway, first: their messages name the real problem
    if data.normals is not None and not checked:
        p, nrm = checked_samples(data.points, data.normals)
        duplicate_pairs_checked(p, nrm, MERGE_TOL * diagonal(p))
    check_not_flat(data.points, f"points of {name}")
    # Clean samples leave a quadric residual that grows with the spacing (as spacing x
    # curvature): the bundled 4,000-point bunny reads 0.063 spacings, clean 4k-point suzanne
    # 0.084, against at most 0.047 for clean clouds of 10k points and more. Below `SPARSE` points
    # the threshold grows as sqrt(SPARSE / n).
    n = len(data.points)
    threshold = NOISY_SPACING * max(1.0, float(np.sqrt(SPARSE / n)))
    report = estimate_noise(data.points, data.normals, threshold=threshold)
    if verbose:
        log(f"{name}: {report.summary()}")
    return bool(report.noisy)


def _offset_fraction(offset) -> float:
    frac = DEFAULT_OFFSET if offset is None else float(offset)
    if not (np.isfinite(frac) and frac > 0):
        raise InputError(f"`offset` must be a positive fraction of the diagonal, got {offset!r}")
    return frac


def constraints_from(
    source,
    normals=None,
    *,
    points: int | None = None,
    sampling: str = "faces",
    offset: float | None = None,
    seed: int = 0,
    subsample: bool = False,
    remove_outliers: bool = False,
    verbose: bool = False,
) -> Constraints:
    """Constraints from a file path (mesh, point cloud with normals, 2-D polyline) or from arrays.

    **Arguments:**
    - `source`: a path, or an (n, d) array of surface points (then `normals` is required).
    - `points`: surface points to use. Default: for meshes, as many samples as vertices, within
      `MESH_MIN_POINTS` to `MESH_MAX_POINTS`; for point clouds, all of them; either at most
      `DEFAULT_POINTS` when `subsample` is set.
    - `subsample`: cap the samples at `DEFAULT_POINTS` when `points` is not given (what the
      dense method wants; the scalable methods take every point).
    - `sampling`: for meshes, `faces` (uniform samples with face normals) or `vertices`
      (area-weighted vertex normals).
    - `offset`: d as a fraction of the bounding-box diagonal (default 0.01).
    - `normals`: for point clouds, an (n, d) array (with an array `source`), or how to get them:
      `"auto"` (or `None`: the default) uses the normals the input has and estimates them
      (`jaxrbf.estimate_normals`, 3-D only) when it has none, saying so on stderr; `"given"`
      requires normals in the input; `"estimate"` ignores any and estimates them. Meshes and
      polylines ignore it (their normals come from their faces and segments).
    - `remove_outliers`: drop statistical outliers of a point cloud first
      (`jaxrbf.remove_outliers` with its defaults).
    """
    c = _sampled(
        source,
        normals,
        _offset_fraction(offset),
        points=points,
        sampling=sampling,
        seed=seed,
        subsample=subsample,
        remove_outliers=remove_outliers,
        verbose=verbose,
    )[3]
    if verbose:
        log(c.report())
    return c


def _sampled(source, normals, frac, **options):
    """`_surface(source, normals, **options)` and the constraints at offset `frac` of the
    diagonal: `(points, normals, diagonal, constraints, noisy, given)`; a noisy cloud's
    off-surface points are validated against its samples only (`between=False`)."""
    p, n, diag, noisy, given = _surface(source, normals, **options)
    c = Constraints.from_points(p, n, frac * diag, between=not noisy)
    return p, n, diag, c, noisy, given


def fit_surface(source, normals=None, **options) -> AbstractModel:
    """Constraints from `source` (see `constraints_from`), then `fit`; every option as for
    `fit_surface_samples`, which also returns the samples."""
    return fit_surface_samples(source, normals, **options)[0]


class Fitted(tuple):
    """What `fit_surface_samples` returns: `(model, points, normals)`, and as `walls` the
    buried samples and their normals (`((k, d), (k, d))`, k = 0 when none), which the fit left
    out and `mesh_fit` keeps as thin cavities (`jaxrbf._cavities`), and as `shells` the samples
    of open pieces that bound no volume (`jaxrbf._winding.shell_samples`), which `mesh_fit`
    meshes as thin slabs (`jaxrbf._cavities.shell_slabs`). When every sample is on a shell,
    `points` and `normals` are empty and the model is the fit of them all without volume
    constraints (signed by the normals near them, unspecified far away)."""

    walls: tuple[np.ndarray, np.ndarray]
    shells: tuple[np.ndarray, np.ndarray]

    def __new__(cls, model, points, normals, walls, shells=None):
        self = super().__new__(cls, (model, points, normals))
        self.walls = walls
        if shells is None:
            d = np.shape(walls[0])[1] if np.ndim(walls[0]) == 2 else 3
            shells = (np.zeros((0, d)), np.zeros((0, d)))
        self.shells = shells
        return self


def _turned_out(n, flipped: bool, turned) -> np.ndarray:
    """The normals `n` turned out as `jaxrbf._winding.oriented` found them, said on stderr."""
    if flipped:
        # every normal pointed into the solid: the fit, the volume constraints and the output's
        # orientation want them out
        n = -n
        log(
            "the normals point into the solid (the samples' winding number reads about -1/2 at "
            "them, not +1/2): flipped, so that they point out"
        )
    if turned is not None and turned.any():
        # parts wound the other way (an artist's model): turned out, part by part
        n = np.where(turned[:, None], -n, n)
        log(
            f"{int(turned.sum()):,} samples whose normals point into the solid (on parts wound "
            "the other way, where the winding number reads about -1/2, or one by one, where it "
            "jumps the wrong way across them): turned out"
        )
    return n


def fit_surface_samples(
    source,
    normals=None,
    *,
    kernel: str | None = None,
    radius: float | None = None,
    degree: int = 1,
    smoothing: float = 0.0,
    denoise="auto",
    solver: str | None = None,
    method: str = "auto",
    points: int | None = None,
    sampling: str = "faces",
    offset: float | None = None,
    seed: int = 0,
    remove_outliers="auto",
    background="auto",
    fill_holes="auto",
    volume="auto",
    shells="auto",
    verbose: bool = False,
) -> Fitted:
    """Constraints from `source` (see `constraints_from`), then `fit`: `(model, points,
    normals)`, the points and normals being the surface samples fitted (hole caps included,
    buried samples left out), which the output must account for.

    `kernel` defaults to `cubic` (r^3) in 3-D and `thin-plate` (r^2 log r) in 2-D, as in the paper,
    but to `linear` (r) for a 3-D partition of unity of 50,000 samples or more, and for one of
    any size that interpolates samples with the normals they came with (a mesh's, a clean
    cloud's own): `default_kernel` says why;
    `radius` (kernels that have one) is a fraction of the diagonal; by default it is set from
    the point spacing (`jaxrbf.default_radius`: 1.75 median nearest-neighbour spacings of the
    surface samples for the Gaussian, 2 for the multiquadrics, 32 for Wendland).
    `method` as for `fit` (`auto`: one dense system up to 15,000 unknowns, a partition of unity
    beyond). For the dense and global methods `solver` defaults to `cg` (Schwarz-preconditioned
    conjugate gradients: 3-4x faster than a dense solve at 12,000 constraints) except for the
    Gaussian, whose fast-decaying spectrum defeats iterative solvers: it gets `lu`.
    `smoothing`: lambda (A + lambda I), in the input's units; `denoise=True` chooses it instead,
    by the held-out error on crops of the input (`jaxrbf.choose_smoothing`; 0 for clean input).
    `remove_outliers=True` drops a point cloud's stray points first (`jaxrbf.remove_outliers`).
    Both default to "auto": a point cloud's scatter across its surface is measured
    (`jaxrbf.estimate_noise`); a noisy cloud loses its strays and is approximated with the
    chosen smoothing, a bare clean cloud (no normals) loses its strays only, and meshes,
    polylines and clean clouds with normals are interpolated as they are. A `smoothing` given
    by hand turns the automatic choice off. `normals` as for `constraints_from`.
    `background`: a dense fit with a kernel that decays (Gaussian, inverse multiquadric) is fitted
    over `jaxrbf.surface_background` of the samples ("auto", the default; True or False), so that
    it has no spurious surface away from the data; the partition of unity has its own coarse
    levels instead.
    `fill_holes` (3-D): where the samples leave a hole (a closed rim of boundary points, such as
    a scan's unseen base), membrane samples over the rim join the input (`jaxrbf.fill_holes`),
    so that the surface caps the hole flat instead of continuing the slopes at its rim; a line
    on stderr says what was capped. "auto" (the default) caps holes only for a partition of
    unity fitted without volume constraints (`volume=False`), whose caps otherwise come from
    its coarse fallback levels (local fits extrapolated into the hole, with kinks where one
    level hands over to the next); the volume constraints' closing samples do that job by
    default, for any shape of hole; True or False for either.
    `volume` (3-D): volume constraints away from the samples and around their boundaries,
    signed by the samples' fast winding number and valued by the distance to the samples or to
    the winding number's closing surface, whichever is nearer (`jaxrbf.volume_constraints`;
    no probes around boundaries when the fit approximates a noisy cloud; a shell of probes 4.5
    spacings off the samples on both sides in every fit), so that f is positive
    outside and negative inside everywhere, not only near the data: an open, multi-part or
    holed input then closes across its holes, without balloons or stray sheets. With them come
    samples of the closing surface itself (w = the surface's own closing level, 1/2 on a
    closed surface), wherever it lies 3 spacings or more from the samples
    (`jaxrbf._winding.closing_samples`), fitted like the input's own (but not returned
    as samples, nor counted by the output's check): the fit then closes a hole where the
    winding number does, a smooth membrane, instead of where its coarse levels extrapolate.
    Samples with the inside on both of their sides (`jaxrbf._winding.buried_samples`: walls
    inside another piece) are left out of the fit and of the samples returned, unless the fit
    approximates a noisy cloud; they come back as the result's `walls` (`Fitted`), which
    `mesh_fit` keeps as thin cavities.
    With them, normals that all point into the solid (the samples' winding number reads about
    -1/2 at them instead of +1/2: `jaxrbf._winding.points_inward`) are turned out first, with a
    line on stderr, and off-surface points that the winding number clearly puts on the other
    side of the surface are dropped (exact fits only: `jaxrbf._winding.contradicted`).
    "auto" (the default) and True add them to 3-D surfaces, False leaves them out.
    `shells` (with the volume constraints): pieces of the samples that bound no volume (a sheet,
    a bowl, a vase, a tube, a car body without its underside: openings of about 15% of their
    area or more, where their winding number reads little more inside than outside,
    `jaxrbf._winding.shell_samples`) are left out of the fit and of the samples returned, and
    come back as the result's `shells`, which `mesh_fit` meshes as thin closed slabs round
    them, instead of closing them with a lid the input does not have. "auto" (the default):
    so for fits that interpolate; for noisy clouds (scans, whose openings are mostly parts no
    view saw) only pieces that read nearer a sheet than a closed surface (a terrain, a facade,
    a single view: `jaxrbf._winding.SHELL_LEVEL_NOISY`). True: the interpolating rule for
    every fit; False: every piece is closed.
    """
    from ._background import BACKGROUND_SAMPLES, surface_background, wants_background
    from ._fit import METHODS
    from .kernels import AbstractKernel, kernel_class

    if method not in METHODS:
        raise InputError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    auto_denoise = isinstance(denoise, str) and denoise == "auto"
    if not auto_denoise and auto_flag(denoise, "denoise", False) and smoothing:
        raise InputError(
            f"give `smoothing` ({smoothing!r}) or `denoise` (which chooses it), not both"
        )
    auto_flag(fill_holes, "fill_holes", False)  # a bad value fails here, before any work
    auto_flag(volume, "volume", False)
    auto_flag(shells, "shells", False)
    frac = _offset_fraction(offset)
    p, n, diag, c, noisy, given = _sampled(
        source,
        normals,
        frac,
        points=points,
        sampling=sampling,
        seed=seed,
        subsample=method == "dense",
        remove_outliers=remove_outliers,
        verbose=verbose,
    )
    if auto_denoise:
        denoise = bool(noisy) and not smoothing
        if denoise and verbose:
            log("noisy input: the fit approximates, with the smoothing chosen by held-out error")
    else:
        denoise = auto_flag(denoise, "denoise", False)
    # the fit approximates: the samples scatter about their surface
    approximate = bool(denoise or smoothing)
    dim = c.points.shape[1]
    surface = np.asarray(c.points[: c.n_surface])
    method = choose_method(method, len(c.points) + n_poly(degree, dim), verbose)
    rebuild = False
    volume = auto_flag(volume, "volume", True) and dim == 3
    # The closing samples of the volume constraints close holes where the winding number does;
    # the membrane caps of `fill_holes` (rims found and spanned by a heuristic) are for fits
    # without them. Measured on a virtual range scan of the bunny (150k bare points, default
    # command): 0.2115% / NC 0.9636 / precision 91.6% with the closing samples alone, 0.2129%
    # / 0.9644 / 91.5% with the caps as well.
    if auto_flag(fill_holes, "fill_holes", method == "partition" and not volume) and dim == 3:
        from ._holes import fill_holes as membrane_caps

        cap, cap_n, report = membrane_caps(p, n)
        if verbose and report.rims:
            log(report.summary())
        if len(cap):
            p, n, rebuild = np.concatenate([p, cap]), np.concatenate([n, cap_n]), True
    if kernel is None:
        # samples interpolated with the normals they came with: a mesh's creases are in them
        kernel = default_kernel(dim, method, len(surface), exact=given and not approximate)
    cls = type(kernel) if isinstance(kernel, AbstractKernel) else kernel_class(kernel)
    r = None
    if cls.has_radius and not isinstance(kernel, AbstractKernel):
        from ._tune import default_radius

        if radius is None:
            r = default_radius(cls.name, surface)
        else:
            r = float(radius) * diagonal(surface)
    elif radius is not None:
        raise InputError(f"the {cls.name} kernel has no radius; leave --radius unset")
    if method == "partition" and offset is None:
        # The partition's patches span a few point spacings; an offset of 1% of the diagonal puts
        # the off-surface points outside them once the points are dense (1M points: ~10
        # spacings), and the local fits then see only zeros. Keep d within reach.
        near = partition_offset(surface)
        if near < DEFAULT_OFFSET:
            if verbose:
                log(
                    f"partition: offset {near:.4f} of the diagonal ({PARTITION_OFFSET_SPACINGS:g} "
                    "point spacings) instead of the default, so that patches hold off-surface points"
                )
            frac, rebuild = near, True
    fitted_p, fitted_n, vc = p, n, None
    walls = (np.zeros((0, p.shape[1])), np.zeros((0, p.shape[1])))
    open_pieces, every, oriented = walls, False, False
    if volume:
        from ._winding import volume_constraints

        t0 = time.perf_counter()
        # A noisy cloud, which the fit approximates, keeps every sample: there the buried test
        # also fires in gaps narrower than its 4 spacings (on a real scan of a machine part, 6
        # samples, whose removal grew 1.4% more surface far from the data).
        exact = not approximate
        if verbose:  # tens of seconds on large or many-holed inputs: say what is under way
            log(f"inside/outside: the winding number of {len(p):,} samples ...")
        spacing, areas, rim = point_spacing(p), None, None
        if auto_flag(shells, "shells", True):
            from ._winding import open_shells

            # by default a noisy cloud is held to the noisy rule (True: the interpolating one)
            noisy = not exact and isinstance(shells, str)
            found, areas, rim = open_shells(p, n, spacing, seed=seed, noisy=noisy, orient=True)
            if found.reoriented is not None and found.reoriented.any():
                n = np.where(found.reoriented[:, None], -n, n)
                fitted_n, rebuild = n, True
                log(
                    f"{int(found.reoriented.sum()):,} samples turned on pieces whose normals "
                    "faced both ways at one place (a soup wound at random, or normals that point "
                    "either way): their signs made to agree along the surface, as for a bare "
                    "cloud"
                )
            n, oriented = _turned_out(n, found.flipped, found.turned), True
            if found.flipped or found.turned.any():
                fitted_n, rebuild = n, True
            if found.mask.any():
                log(found.summary())
                open_pieces = (p[found.mask], n[found.mask])
                rest = ~found.mask
                # every piece was judged or went with the nearest judged piece: the rest is
                # whole pieces, or nothing
                if rest.any():
                    # the rest is fitted and closed without them (near a shell, w reads
                    # +-1/2: the rest's volume constraints would close across it)
                    p, n, rebuild = p[rest], n[rest], True
                    spacing, areas, rim = point_spacing(p), None, None
                else:
                    # all shells: the mesh is the slabs alone, and the model the fit of the
                    # samples without volume constraints: f is signed by the normals near the
                    # shells and says nothing far from them (their winding number has no
                    # inside to give; closing them first cost 288 s of 374 at 100k samples of
                    # the beetle, for a surface no output used)
                    every = True
        if every:
            if verbose:
                log(
                    "every sample is on an open shell: fitted without volume constraints (the "
                    "mesh is their slabs)"
                )
        else:
            vc = volume_constraints(
                p,
                n,
                spacing,
                areas,
                rims=exact,
                close=True,
                bury=exact,
                orient=not oriented,
                rim=rim,
            )
            if vc.flipped or vc.turned.any():
                n, rebuild = _turned_out(n, vc.flipped, vc.turned), True
            if verbose:
                log(f"{vc.summary()} in {time.perf_counter() - t0:.1f} s")
            if vc.buried.any():
                # walls inside the solid: not fitted (the output keeps them as thin cavities)
                walls = (p[vc.buried], n[vc.buried])
                p, n, rebuild = p[~vc.buried], n[~vc.buried], True
            fitted_p, fitted_n = p, n
            if len(vc.closing):
                # fitted like samples; the samples returned (the meshing box, the output's check)
                # stay the input's own
                fitted_p = np.concatenate([p, vc.closing])
                fitted_n = np.concatenate([n, vc.closing_normals])
                rebuild = True
    if approximate != bool(noisy):
        # `_sampled` validated against the surface between the samples where they are not noisy;
        # the fit's own choice decides (`Constraints.from_points(between=...)`)
        rebuild = True
    if rebuild:  # once, whatever asked for it
        c = Constraints.from_points(fitted_p, fitted_n, frac * diag, between=not approximate)
    if vc is not None and not approximate:
        from ._winding import contradicted

        # An off-surface point the winding number clearly puts on the other side of the surface
        # (an outside point of a hidden face that ends inside the body, an inside point of a
        # folded fin's flipped triangle) would pull the surface out to it: it is dropped.
        # Exact fits only: a noisy cloud's w is no sharper than its scatter.
        q, v = c.off_surface()
        against = contradicted(q, v > 0, vc.tree)
        if against.any():
            c = c.without_off_surface(against)
            if verbose:
                log(
                    f"{int(against.sum()):,} off-surface points dropped: the winding number puts "
                    "them on the other side of the surface"
                )
    if vc is not None:
        c = c.with_volume(vc.points, vc.values)
    if verbose:
        log(c.report())
    if denoise:
        from ._denoise import choose_smoothing

        smoothing = choose_smoothing(
            p,
            n,
            kernel=kernel if isinstance(kernel, AbstractKernel) else cls.name,
            offset=frac * diag,
            radius=r,
            degree=degree,
            seed=seed,
            verbose=verbose,
        ).smoothing
    if solver is None and method != "partition":
        solver = "lu" if cls.name == "gaussian" else "cg"
    bg = None
    if wants_background(background, cls.name) and (method == "dense" or background is True):
        if verbose:
            log(
                f"background: a global polyharmonic fit of {min(len(p), BACKGROUND_SAMPLES):,} of the "
                "samples"
            )
        bg = surface_background(p, n)
    model = fit(
        c,
        kernel=kernel,
        radius=r,
        degree=degree,
        smoothing=smoothing,
        solver=solver,
        method=method,
        seed=seed,
        background=bg,
        verbose=verbose,
    )
    if every:
        return Fitted(model, p[:0], n[:0], walls, open_pieces)
    return Fitted(model, p, n, walls, open_pieces)


#: The default meshing grid follows the samples' density: `RESOLUTION_AT` samples along the
#: longest side for `SPACINGS_AT` median point spacings along it, growing as the
#: `RESOLUTION_POWER` of the spacings, within `RESOLUTION_RANGE` (3-D). Measured on the bunny
#: (the grids at which jaxrbf's Chamfer-L1 and normal consistency reach Poisson depth 9's): 256
#: at 10k samples (140 spacings along the side), 320-400 at 100k (440), 640 at 1M (1,400); a
#: grid finer than the samples adds vertices, not accuracy. In 2-D, `RESOLUTION_2D` samples per
#: point spacing (contouring is cheap, and thin slits need several cells across).
RESOLUTION_AT, SPACINGS_AT, RESOLUTION_POWER = 256, 140, 0.4
RESOLUTION_RANGE = (128, 1024)
RESOLUTION_2D, RESOLUTION_2D_RANGE = 6, (256, 2048)


def default_resolution(points: np.ndarray, spacing: float | None = None) -> int:
    """The meshing grid (samples along the longest side) for surface samples `points` (see
    `RESOLUTION_AT`), whose point `spacing` is measured when not given: a multiple of 16."""
    side = float(np.max(np.ptp(points, axis=0)))
    if spacing is None:
        spacing = point_spacing(points)
    spacings = side / max(spacing, 1e-12 * side)
    if points.shape[1] == 2:
        r, (lo, hi) = RESOLUTION_2D * spacings, RESOLUTION_2D_RANGE
    else:
        r = RESOLUTION_AT * (spacings / SPACINGS_AT) ** RESOLUTION_POWER
        lo, hi = RESOLUTION_RANGE
    return int(np.clip(16 * round(r / 16), lo, hi))


#: Padding of the meshing box (fraction of the centres' box) for a second try when the surface
#: leaves the default box (5%): a hole filled by the implicit surface often bulges out of it.
WIDE_PADDING = 0.3


def mesh_closed(
    model,
    resolution: int = 128,
    *,
    project: bool = False,
    progress=None,
    verbose=False,
    bounds=None,
):
    """`polygonize(model)` (in `bounds`, default the model's box grown by 5%), once more in a
    box grown by `WIDE_PADDING` when the mesh is open (the surface left the box: typically
    where it fills a hole of the input). Returns the watertight mesh if either is, else the
    first."""
    from ._clean import is_watertight
    from ._polygonize import _bounds, polygonize

    lo, hi = _bounds(model, bounds, 3, 0.05)
    mesh = polygonize(
        model, resolution=resolution, project=project, progress=progress, bounds=(lo, hi)
    )
    if is_watertight(mesh):
        return mesh
    pad = WIDE_PADDING * float(np.max(hi - lo)) / 1.1
    wide = polygonize(
        model,
        resolution=resolution,
        project=project,
        progress=progress,
        bounds=(lo - pad, hi + pad),
    )
    if is_watertight(wide):
        if verbose:
            log(f"the surface left the meshing box: meshed again with {WIDE_PADDING:.0%} padding")
        return wide
    return mesh


def meshing_box(samples: np.ndarray, padding: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """The box of `samples` grown by `padding` of its largest side on every side: where the
    surface of a fit of those samples is meshed."""
    lo, hi = samples.min(axis=0), samples.max(axis=0)
    pad = padding * float(np.max(hi - lo))
    return lo - pad, hi + pad


def reconstruct(
    source,
    normals=None,
    *,
    resolution: int | None = None,
    project: bool = False,
    progress: bool | None = None,
    verbose: bool = False,
    **options,
):
    """`source` (a mesh, point cloud or polyline file, or points + normals) to a surface.

    **Arguments:** `resolution` and `project` as for `polygonize` (default resolution:
    `default_resolution` of the samples, which follows their density); every other option as for
    `fit_surface` (`kernel`, `radius`, `degree`, `smoothing`, `denoise`, `solver`, `method`,
    `points`, `sampling`, `offset`, `seed`, `remove_outliers`); `normals` as for
    `constraints_from`.

    **Returns:** a `jaxrbf.io.Mesh` for 3-D input; for a 2-D polyline, a list of (k, 2) curves.
    """
    fitted = fit_surface_samples(source, normals, verbose=verbose, **options)
    model, samples, _ = fitted
    return mesh_fit(
        model,
        samples,
        resolution=resolution,
        project=project,
        progress=progress,
        verbose=verbose,
        walls=fitted.walls,
        shells=fitted.shells,
    )


def mesh_fit(
    model,
    samples: np.ndarray,
    *,
    resolution: int | None = None,
    project: bool = False,
    progress: bool | None = None,
    verbose: bool = False,
    walls=None,
    shells=None,
):
    """The surface of a fit of the surface `samples`: a mesh (`mesh_closed`) in 3-D, curves
    (`contour`) in 2-D, at `resolution` (default: `default_resolution(samples)`), checked
    against the samples before it is returned (`jaxrbf._accounts.check_output`): an output
    that loses part of its input, or that is mostly surface far from every sample, is a
    `SolveError` that says what went wrong, never a result. Mesh components with no sample
    near are dropped first (`drop_unsupported`). `walls`: the buried samples and their normals
    that the fit left out (`Fitted.walls`), kept in a mesh as thin cavities
    (`jaxrbf._cavities`) and checked with the samples. `shells`: the samples of open pieces and
    their normals (`Fitted.shells`), meshed as thin closed slabs round them
    (`jaxrbf._cavities.shell_slabs`) beside the fit's surface (instead of it, when `samples` is
    empty) and checked with the samples."""
    from ._accounts import check_curves, check_output
    from ._polygonize import contour, drop_unsupported
    from .io import Mesh

    samples = np.asarray(samples, dtype=float)
    every = samples
    if shells is not None and len(shells[0]):
        every = np.concatenate([samples.reshape(-1, shells[0].shape[1]), shells[0]])
    if (len(every) if every.ndim == 2 else 0) < 2:
        raise ValueError(
            f"mesh_fit: {len(every)} samples to mesh; it needs the fit's samples (and, when every "
            "sample lay on an open shell, its shells: pass shells=fitted.shells)"
        )
    spacing = point_spacing(every)
    if resolution is None:
        resolution = default_resolution(every, spacing)
        if verbose:
            log(
                f"meshing on a grid of {resolution} samples along the longest side (from the "
                "samples' point spacing; set --resolution to change it)"
            )
    t0 = time.perf_counter()
    if model.dim == 2:
        out = contour(model, resolution=resolution, progress=progress)
        if verbose:
            log(f"{len(out)} curves in {time.perf_counter() - t0:.1f} s")
        _accounted(check_curves(out, samples), verbose)
        return out
    lo, hi = meshing_box(every)
    cell = float(np.max(hi - lo)) / max(int(np.max(resolution)) - 1, 1)
    if len(samples):
        mesh = mesh_closed(
            model,
            resolution=resolution,
            project=project,
            progress=progress,
            verbose=verbose,
            bounds=(lo, hi),
        )
        mesh = drop_unsupported(mesh, samples, spacing, cell, verbose=verbose)
    else:  # every sample on an open shell: the slabs are the surface
        mesh = Mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    if walls is not None and len(walls[0]):
        from ._cavities import with_cavities

        mesh = with_cavities(mesh, model, *walls, spacing, cell, verbose=verbose)
        samples = np.concatenate([samples, walls[0]])
    if shells is not None and len(shells[0]):
        from ._cavities import with_shells

        mesh = with_shells(mesh, *shells, spacing, cell, verbose=verbose)
        samples = np.concatenate([samples.reshape(-1, 3), shells[0]])
    if verbose:
        log(
            f"mesh of {len(mesh.vertices):,} vertices, {len(mesh.faces):,} faces in "
            f"{time.perf_counter() - t0:.1f} s"
        )
    _accounted(check_output(mesh.vertices, mesh.faces, samples), verbose)
    return mesh


def _accounted(report, verbose: bool) -> None:
    """Say what `report` (`check_output` / `check_curves`) found; a failure is a `SolveError`."""
    from ._errors import SolveError

    if verbose or not report.ok:
        log(report.summary())
    if not report.ok:
        raise SolveError(f"the output does not account for its input: {report.problem}")
