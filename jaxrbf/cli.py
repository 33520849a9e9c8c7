"""The `jaxrbf` command: a thin shell over the one-shot helpers.

Progress and errors go to stderr, results to files. Every output is written atomically, and bad
input ends with a one-line error and exit status 2 (no traceback, no output file).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

from .io import MESH_OUTPUTS as MESH_OUT
from .io import POLYLINE_OUTPUTS as CURVE_OUT


def _fit_options(p: argparse.ArgumentParser) -> None:
    from ._solve import SOLVERS
    from .kernels import KERNELS

    g = p.add_argument_group("fitting")
    g.add_argument(
        "--points",
        type=int,
        help="surface points to use (default: as many samples of a mesh as it has vertices, "
        "10,000 to 100,000; every point of a point cloud; at most 4000 with --method dense)",
    )
    g.add_argument(
        "--method",
        choices=("auto", "dense", "partition", "global"),
        default="auto",
        help="dense: one global system; partition: blended local fits (millions of points); "
        "global: exact interpolation with greedy centre selection; auto (default): dense up to "
        "15,000 unknowns, partition beyond",
    )
    g.add_argument(
        "--sampling",
        choices=("faces", "vertices"),
        default="faces",
        help="for meshes: uniform samples with face normals, or vertices with area-weighted normals",
    )
    g.add_argument(
        "--kernel",
        choices=list(KERNELS),
        help="default: cubic in 3-D (linear for the partition method from 50,000 samples, "
        "and for it at any size when the input's own normals are interpolated: a mesh, a clean "
        "cloud with normals), thin-plate in 2-D",
    )
    g.add_argument(
        "--radius",
        type=float,
        help="kernel radius, fraction of the bounding-box diagonal (default: from the point "
        "spacing, 1.75 median spacings for gaussian, 2 for the multiquadrics, 32 for wendland)",
    )
    g.add_argument(
        "--offset",
        type=float,
        help="off-surface distance d, fraction of the diagonal (default 0.01)",
    )
    g.add_argument(
        "--smoothing", type=float, default=0.0, help="lambda added to the diagonal (default 0)"
    )
    g.add_argument(
        "--solver",
        choices=SOLVERS,
        help="linear solver of the dense and global methods (default cg; lu for the gaussian "
        "kernel)",
    )
    g.add_argument(
        "--degree", type=int, choices=(-1, 0, 1), default=1, help="polynomial degree (default 1)"
    )
    g.add_argument("--seed", type=int, default=0, help="seed of the surface sampling")
    g.add_argument(
        "--normals",
        choices=("auto", "given", "estimate"),
        default="auto",
        help="point clouds: use the file's normals (given), estimate them from the points "
        "(estimate: PCA + minimum-spanning-tree orientation), or use them if present and "
        "estimate otherwise (auto, default)",
    )
    g.add_argument(
        "--remove-outliers",
        nargs="?",
        choices=("auto", "yes", "no"),
        const="yes",
        default="auto",
        help="point clouds: drop statistical outliers (mean distance to 16 neighbours more "
        "than 2 standard deviations above the mean, then points farther from their "
        "neighbours' plane than 6x its thickness) first; auto (default): for clouds without "
        "normals and for noisy ones",
    )
    g.add_argument(
        "--holes",
        choices=("auto", "fill", "keep"),
        default="auto",
        help="3-D: also cap the holes of the samples (closed rims of boundary points) with "
        "membrane samples before fitting (fill), or not (keep); auto (default): keep, since the "
        "volume constraints close every hole on the winding number's closing surface (fill "
        "only for a partition fitted without them)",
    )
    g.add_argument(
        "--open-pieces",
        choices=("auto", "thicken", "close"),
        default="auto",
        help="3-D: pieces of the input that bound no volume (a sheet, a bowl, a tube, a car "
        "body without its underside: openings of about 15%% of their area or more) are meshed "
        "as thin closed slabs round them (thicken) or closed like holes (close); auto "
        "(default): thicken, except that in a noisy scan only sheet-like pieces (a terrain, a "
        "facade, a single view) are thickened and the rest is closed",
    )
    g.add_argument(
        "--denoise",
        nargs="?",
        choices=("auto", "yes", "no"),
        const="yes",
        default="auto",
        help="noisy input: approximate instead of interpolating, with the smoothing lambda "
        "chosen by the held-out error on crops of the input (stays 0 for clean input); auto "
        "(default): when the point cloud's scatter across its surface says it is noisy",
    )


def _mesh_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("meshing")
    g.add_argument(
        "--resolution",
        type=int,
        default=None,
        help="grid samples along the longest side (default: from the input's point spacing, "
        "128 to 1024 in 3-D; 128 for `mesh` of a model saved without its samples)",
    )
    g.add_argument("--project", action="store_true", help="Newton-project vertices onto f = 0")


def _tune_options(p: argparse.ArgumentParser) -> None:
    from .kernels import KERNELS

    g = p.add_argument_group("tuning")
    g.add_argument(
        "--points", type=int, help="surface samples (default 2000; every fit is a dense solve)"
    )
    g.add_argument("--sampling", choices=("faces", "vertices"), default="faces")
    g.add_argument(
        "--kernel", choices=list(KERNELS), help="default: cubic in 3-D, thin-plate in 2-D"
    )
    g.add_argument(
        "--params",
        nargs="+",
        choices=("offset", "radius", "smoothing"),
        help="what to tune (default: offset, and radius for kernels with one)",
    )
    g.add_argument(
        "--objective",
        choices=("held-out", "kfold", "loocv"),
        default="held-out",
        help="held-out error (default), 5-fold error, or Rippa's leave-one-out error",
    )
    g.add_argument(
        "--optimizer",
        choices=("bfgs", "lm"),
        default="bfgs",
        help="optimistix BFGS (default) or Levenberg-Marquardt",
    )
    g.add_argument("--max-steps", type=int, default=4, help="optimiser steps (default 4)")
    g.add_argument("--radius", type=float, help="starting radius, fraction of the diagonal")
    g.add_argument("--offset", type=float, help="starting offset, fraction of the diagonal")
    g.add_argument(
        "--smoothing", type=float, default=0.0, help="lambda (the start, if tuned; default 0)"
    )
    g.add_argument("--degree", type=int, choices=(-1, 0, 1), default=1)
    g.add_argument("--seed", type=int, default=0, help="seed of the surface sampling")


def _tristate(value: str):
    """An "auto" / "yes" / "no" option as "auto", True or False."""
    return {"auto": "auto", "yes": True, "no": False}[value]


def _tune_source(source, args):
    """`(points or path, normals or None)` for `tune_surface`: a point-cloud file without normals
    (or with --normals estimate) gets estimated normals, as `reconstruct` would."""
    from . import io
    from ._reconstruct import _clean_cloud, _normals_mode

    if source[1] is not None or not isinstance(source[0], (str, os.PathLike)):
        return source
    mode, _ = _normals_mode(getattr(args, "normals", "auto"))
    outliers = getattr(args, "remove_outliers", "no") == "yes"
    if mode == "given" and not outliers:
        return source
    data = io.read_input(source[0])
    if not isinstance(data, io.PointCloud) or (
        data.normals is not None and mode == "auto" and not outliers
    ):
        return source
    data = _clean_cloud(data, os.fspath(source[0]), mode, outliers, not args.quiet)
    return data.points, data.normals


def _tuned(source, args, **extra):
    """`tune_surface` on the CLI's options: (model, report)."""
    import optimistix as optx

    from ._tune import tune_surface

    solver = optx.LevenbergMarquardt(rtol=1e-3, atol=1e-3) if extra.pop("lm", False) else None
    source = _tune_source(source, args)
    return tune_surface(
        source[0],
        source[1],
        kernel=args.kernel,
        offset=args.offset,
        radius=args.radius,
        smoothing=args.smoothing,
        degree=args.degree,
        points=args.points,
        sampling=args.sampling,
        seed=args.seed,
        solver=solver,
        verbose=not args.quiet,
        **extra,
    )


class _Parser(argparse.ArgumentParser):
    """argparse with its errors on one line (`jaxrbf: error: ...`), as every other error."""

    def error(self, message: str):
        self.exit(2, f"jaxrbf: error: {message} (see `{self.prog} --help`)\n")


def build_parser() -> argparse.ArgumentParser:
    from . import __version__

    parser = _Parser(
        prog="jaxrbf",
        description="Implicit surfaces from radial basis functions (meshes, point clouds, polylines).",
    )
    parser.add_argument("--version", action="version", version=f"jaxrbf {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    from .features import add_features_parser

    add_features_parser(sub)

    r = sub.add_parser(
        "reconstruct", help="input file -> surface mesh (or curves, for a 2-D polyline)"
    )
    r.add_argument(
        "input",
        nargs="?",
        help="mesh (.obj .ply .stl .off), point cloud with or without normals (.ply .xyz .txt .pts .csv .npz; an .obj of vertices alone) or polyline (2-column .csv, .npy)",
    )
    r.add_argument(
        "-o",
        "--output",
        required=True,
        help="mesh (.ply .obj .stl .off) or, in 2-D, curves (.csv .npz)",
    )
    r.add_argument("--example", choices=("bunny",), help="use the bundled example instead of INPUT")
    _fit_options(r)
    _mesh_options(r)
    r.add_argument(
        "--preview",
        metavar="VIEW.png",
        help="also ray-march a 512x512 picture of the surface (3-D) to this PNG",
    )
    r.add_argument(
        "--tune",
        action="store_true",
        help="choose the offset (and the kernel radius) by minimising the held-out error first "
        "(see `jaxrbf tune`; dense fit of --points samples, default 2000)",
    )
    r.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")

    f = sub.add_parser("fit", help="input file -> model (.npz)")
    f.add_argument("input", nargs="?")
    f.add_argument("-o", "--output", required=True, help="model file (.npz)")
    f.add_argument("--example", choices=("bunny",), help="use the bundled example instead of INPUT")
    _fit_options(f)
    f.add_argument("-q", "--quiet", action="store_true")

    m = sub.add_parser("mesh", help="model (.npz) -> mesh (or curves for a 2-D model)")
    m.add_argument("model")
    m.add_argument("-o", "--output", required=True)
    _mesh_options(m)
    m.add_argument("-q", "--quiet", action="store_true")

    v = sub.add_parser("render", help="model (.npz) -> ray-marched picture (.png)")
    v.add_argument("model")
    v.add_argument("-o", "--output", required=True, help="picture (.png)")
    v.add_argument(
        "--size", type=int, nargs=2, default=(512, 512), metavar=("W", "H"), help="default 512 512"
    )
    v.add_argument(
        "--azimuth", type=float, default=30.0, help="degrees about the up axis (default 30)"
    )
    v.add_argument(
        "--elevation", type=float, default=20.0, help="degrees above the horizon (default 20)"
    )
    v.add_argument("--up", choices=("x", "y", "z", "-x", "-y", "-z"), default="y", help="default y")
    v.add_argument("--fov", type=float, default=35.0, help="vertical field of view (default 35)")
    v.add_argument("--shadows", action="store_true", help="cast shadows from the key light")
    v.add_argument("--occlusion", action="store_true", help="ambient occlusion")
    v.add_argument("-q", "--quiet", action="store_true")

    t = sub.add_parser(
        "tune", help="input file -> model (.npz) with the offset and kernel radius tuned"
    )
    t.add_argument("input", nargs="?")
    t.add_argument("-o", "--output", required=True, help="model file (.npz)")
    t.add_argument("--example", choices=("bunny",), help="use the bundled example instead of INPUT")
    _tune_options(t)
    t.add_argument("-q", "--quiet", action="store_true")

    e = sub.add_parser("evaluate", help="compare a mesh with a reference mesh")
    e.add_argument("mesh")
    e.add_argument("--reference", required=True)
    e.add_argument(
        "--samples", type=int, default=100_000, help="surface samples per mesh (default 100000)"
    )
    e.add_argument(
        "--threshold", type=float, default=0.01, help="F-score threshold, fraction of the diagonal"
    )
    e.add_argument("--json", action="store_true", help="print JSON instead of a table")
    return parser


def _check_output(path: str, allowed: tuple[str, ...] | None, what: str = "output") -> None:
    """Refuse, before any work, an output path that cannot be written (`jaxrbf.io.check_output`)."""
    from .io import check_output

    check_output(path, allowed, what)


#: Least grid samples along the longest side that `--resolution` accepts.
MIN_RESOLUTION = 4


def _positive(name: str, value, strict: bool = True) -> None:
    from ._errors import InputError

    if value is None:
        return
    if not (np.isfinite(value) and (value > 0 if strict else value >= 0)):
        need = "a positive number" if strict else "a number >= 0"
        raise InputError(f"{name} must be {need}, got {value}")


def _check_options(args) -> None:
    """Refuse bad or hostile option values up front, before any file is read or fit: sizes
    against the memory available, angles and distances against their ranges."""
    from ._errors import InputError

    points = getattr(args, "points", None)
    if points is not None:
        if points < 1:
            raise InputError(f"--points must be at least 1, got {points}")
        from ._partition import check_memory

        try:  # the partition fit: three constraints per sample (on, outside, inside)
            check_memory(3 * points, 3)
        except InputError as e:
            raise InputError(f"--points {points:,} is too many for this machine: {e}") from None
    resolution = getattr(args, "resolution", None)
    if resolution is not None and resolution < MIN_RESOLUTION:
        raise InputError(
            f"--resolution must be at least {MIN_RESOLUTION} samples along the longest side, got "
            f"{resolution}"
        )
    for name in ("radius", "offset"):
        _positive(f"--{name}", getattr(args, name, None))
    _positive("--smoothing", getattr(args, "smoothing", None), strict=False)
    if args.command == "render":
        if not 0 < args.fov < 180:
            raise InputError(
                f"--fov must be an angle between 0 and 180 degrees (exclusive), got {args.fov:g}"
            )
        for name in ("azimuth", "elevation"):
            if not np.isfinite(getattr(args, name)):
                raise InputError(f"--{name} must be a finite angle in degrees")
        if not -90 < args.elevation < 90:
            raise InputError(
                f"--elevation must be between -90 and 90 degrees (exclusive), got "
                f"{args.elevation:g}"
            )
        from ._util import check_memory as check_bytes
        from .render import RENDER_PIXEL_BYTES

        w, h = args.size
        if w < 1 or h < 1:
            raise InputError(f"--size must be two positive integers (width, height), got {w} {h}")
        check_bytes(RENDER_PIXEL_BYTES * w * h, f"--size {w} {h}", "use a smaller --size")
    if args.command == "evaluate":
        if args.samples < 1:
            raise InputError(f"--samples must be at least 1, got {args.samples}")
        from ._util import check_memory as check_bytes

        check_bytes(512 * args.samples, f"--samples {args.samples:,}", "use fewer --samples")
        _positive("--threshold", args.threshold)


def _check_resolution(args, source=None, model=None) -> None:
    """Refuse a `--resolution` whose grid does not fit in memory, before the fit: over the
    model's box when there is a model, else over the input's box (read once for this)."""
    from . import io
    from ._polygonize import check_resolution

    if getattr(args, "resolution", None) is None:
        return
    if model is not None:
        lo, hi = (np.asarray(b, dtype=float) for b in model.bounds())
    else:
        data = source[0] if source[1] is not None else None
        if data is None:
            got = io.read_input(source[0])
            data = got.vertices if not isinstance(got, io.PointCloud) else got.points
        data = np.asarray(data, dtype=float)
        lo, hi = data.min(axis=0), data.max(axis=0)
    extent = hi - lo
    if not extent.max() > 0:
        return  # one point: the fit refuses it
    extent = np.where(extent > 0, extent, extent.max()) * 1.1  # the grid's padding
    check_resolution(args.resolution, extent, name="--resolution")


def _source(args):
    from ._errors import InputError
    from ._reconstruct import example

    if args.example and args.input:
        raise InputError("give INPUT or --example, not both")
    if args.example:
        return example(args.example)
    if not args.input:
        raise InputError("no input: give an INPUT file or --example bunny")
    return args.input, None


def _fit_kwargs(args) -> dict:
    return dict(
        kernel=args.kernel,
        radius=args.radius,
        degree=args.degree,
        smoothing=args.smoothing,
        solver=args.solver,
        method=args.method,
        points=args.points,
        sampling=args.sampling,
        offset=args.offset,
        seed=args.seed,
        remove_outliers=_tristate(args.remove_outliers),
        denoise=_tristate(args.denoise),
        fill_holes={"auto": "auto", "fill": True, "keep": False}[args.holes],
        shells={"auto": "auto", "thicken": True, "close": False}[args.open_pieces],
        verbose=not args.quiet,
    )


def _normals_arg(source, args):
    """The `normals` argument of `fit_surface`: the arrays' normals, or the --normals mode."""
    if source[1] is not None and args.normals != "estimate":
        return source[1]
    return args.normals


def _write_surface(model, args, samples=None, walls=None, shells=None):
    """Mesh (or contour) `model` to `args.output`; returns the mesh (3-D) or None. With the
    fit's surface `samples`, the grid follows their spacing and the output is checked against
    them before it is written (`jaxrbf._reconstruct.mesh_fit`, which keeps the fit's `walls` as
    thin cavities and meshes its open `shells` as thin slabs)."""
    from . import io
    from ._constraints import log
    from ._polygonize import contour
    from ._reconstruct import mesh_closed, mesh_fit

    t0 = time.perf_counter()
    progress = None if args.quiet else True
    if samples is not None:
        out = mesh_fit(
            model,
            samples,
            resolution=args.resolution,
            project=args.project,
            progress=progress,
            verbose=not args.quiet,
            walls=walls,
            shells=shells,
        )
        if model.dim == 2:
            io.write_polylines(args.output, out)
            what = f"{len(out)} curves"
        else:
            mesh = out
            io.write_mesh(args.output, mesh)
            what = f"{len(mesh.vertices):,} vertices, {len(mesh.faces):,} faces"
    elif model.dim == 2:
        curves = contour(model, resolution=args.resolution or 128, progress=progress)
        io.write_polylines(args.output, curves)
        what = f"{len(curves)} curves"
    else:
        mesh = mesh_closed(
            model,
            resolution=args.resolution or 128,
            project=args.project,
            progress=progress,
            verbose=not args.quiet,
        )
        io.write_mesh(args.output, mesh)
        what = f"{len(mesh.vertices):,} vertices, {len(mesh.faces):,} faces"
    if not args.quiet:
        log(f"wrote {args.output}: {what} ({time.perf_counter() - t0:.1f} s)")
    return None if model.dim == 2 else mesh


def _log_topology(source, mesh) -> None:
    """Boundary loops of the input (when it is a mesh file) and whether the output is closed."""
    from . import io
    from ._clean import boundary_loops, is_watertight
    from ._constraints import log

    if source[1] is None and isinstance(source[0], (str, os.PathLike)):
        data = io.read_input(source[0])
        if isinstance(data, io.Mesh):
            # vertices with equal coordinates are one (a soup repeats them face by face)
            _, same = np.unique(data.vertices, axis=0, return_inverse=True)
            loops = boundary_loops(same.reshape(-1)[data.faces])
            log(
                f"input mesh has {loops} boundary loop{'s' if loops != 1 else ''}"
                + (" (holes, filled by the implicit surface)" if loops else "")
            )
    tight = is_watertight(mesh)
    log(
        "output mesh is watertight"
        if tight
        else "output mesh is not watertight (the surface leaves the grid, or has open edges)"
    )


def _write_picture(model, path: str, args) -> None:
    """Ray-march `model` to the PNG `path` (camera options from `args` where it has them)."""
    from ._constraints import log
    from ._errors import InputError
    from .render import Camera, render

    if model.dim != 3:
        raise InputError(f"render draws 3-D models; '{path}' would show a {model.dim}-D one")
    t0 = time.perf_counter()
    lo, hi = (np.asarray(b, dtype=float) for b in model.bounds())
    pad = 0.02 * float((hi - lo).max())
    camera = Camera.orbit(
        (lo - pad, hi + pad),
        getattr(args, "azimuth", 30.0),
        getattr(args, "elevation", 20.0),
        up=getattr(args, "up", "y"),
        fov=getattr(args, "fov", 35.0),
        size=tuple(getattr(args, "size", (512, 512))),
    )
    picture = render(
        model,
        camera,
        shadows=getattr(args, "shadows", False),
        ambient_occlusion=getattr(args, "occlusion", False),
        progress=None if args.quiet else True,
    )
    picture.save(path)
    if not args.quiet:
        st = picture.stats
        log(
            f"wrote {path}: {camera.width}x{camera.height}, {st['hits']:,} surface pixels "
            f"({time.perf_counter() - t0:.1f} s)"
        )


def _out_kinds(source) -> tuple[str, ...]:
    """Allowed output extensions for reconstruct: curves for 2-D input, meshes otherwise."""
    if isinstance(source, tuple) and source[1] is not None:
        return MESH_OUT if source[0].shape[1] == 3 else CURVE_OUT
    ext = os.path.splitext(str(source[0]))[1].lower()
    return CURVE_OUT if ext in (".csv", ".npy") else MESH_OUT


def _run(args) -> int:
    from . import io
    from ._constraints import log
    from ._reconstruct import fit_surface_samples
    from ._serialize import load, load_fit, save

    _check_options(args)
    if args.command == "reconstruct":
        source = _source(args)
        _check_output(args.output, _out_kinds(source))
        if args.preview:
            _check_output(args.preview, (".png",), "--preview")
        _check_resolution(args, source)
        if args.tune:
            from ._errors import InputError

            if args.method not in ("auto", "dense") or args.solver not in (None, "lu", "cholesky"):
                raise InputError(
                    "--tune fits one dense system per step: use it with --method dense (or auto) "
                    "and --solver lu or cholesky (or none)"
                )
            if args.denoise == "yes":
                raise InputError(
                    "--tune and --denoise are separate choices: --denoise picks the smoothing for "
                    "a fit of every point; to tune it, use `jaxrbf tune --params offset smoothing "
                    "--smoothing 1e-6` (a starting lambda > 0)"
                )
            model, _ = _tuned(source, args)
            samples = walls = shells = None
        else:
            fitted = fit_surface_samples(source[0], _normals_arg(source, args), **_fit_kwargs(args))
            model, samples, _ = fitted
            walls, shells = fitted.walls, fitted.shells
        mesh = _write_surface(model, args, samples, walls, shells)
        if mesh is not None and not args.quiet:
            _log_topology(source, mesh)
        if args.preview and model.dim == 3:
            if shells is not None and len(shells[0]):
                log(
                    "note: the preview ray-traces the fit's f = 0; the open shells are in the mesh "
                    "as thin slabs, not in f (which, fitted without them or without an inside "
                    "to give, shows them differently or not at all)"
                )
            _write_picture(model, args.preview, args)
    elif args.command == "fit":
        _check_output(args.output, (".npz",))
        source = _source(args)
        fitted = fit_surface_samples(source[0], _normals_arg(source, args), **_fit_kwargs(args))
        model, samples, normals = fitted
        # the samples go with the model, so that `jaxrbf mesh` meshes it as reconstruct does
        save(
            model,
            args.output,
            samples=samples,
            normals=normals,
            walls=fitted.walls,
            shells=fitted.shells,
        )
        if not args.quiet:
            log(f"wrote {args.output}")
    elif args.command == "tune":
        _check_output(args.output, (".npz",))
        source = _source(args)
        if args.max_steps < 1:
            from ._errors import InputError

            raise InputError(f"--max-steps must be at least 1, got {args.max_steps}")
        model, report = _tuned(
            source,
            args,
            params=args.params,
            objective=args.objective,
            max_steps=args.max_steps,
            lm=args.optimizer == "lm",
        )
        save(model, args.output)
        print(report.summary())
        for k, point in enumerate(report.path):
            print(f"  step {k}: " + ", ".join(f"{a} {b:.5g}" for a, b in point.items()))
        if not args.quiet:
            log(f"wrote {args.output}")
    elif args.command == "mesh":
        _check_output(args.output, None)
        model, samples, _ = fitted = load_fit(args.model)
        _check_output(args.output, MESH_OUT if model.dim == 3 else CURVE_OUT)
        _check_resolution(args, model=model)
        if samples is None:
            _write_surface(model, args)
        else:
            _write_surface(model, args, samples, fitted.walls, fitted.shells)
    elif args.command == "features":
        from .features import run_features

        _check_output(args.output, None)
        if args.polylines:
            _check_output(args.polylines, None, "--polylines")
        _check_resolution(args, model=load(args.model))
        return run_features(args)
    elif args.command == "render":
        _check_output(args.output, (".png",))
        model = load(args.model)
        _write_picture(model, args.output, args)
    elif args.command == "evaluate":
        from .metrics import evaluate

        scores = evaluate(
            io.read_mesh(args.mesh),
            io.read_mesh(args.reference),
            n=args.samples,
            threshold=args.threshold,
        )
        if args.json:
            print(json.dumps(scores, indent=2))
        else:
            for k, v in scores.items():
                print(f"{k:20s} {v:.6g}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `jaxrbf` command; returns the exit status."""
    args = build_parser().parse_args(argv)
    from ._errors import JaxRBFError

    try:
        return _run(args)
    except JaxRBFError as e:
        print(f"jaxrbf: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"jaxrbf: error: {e.strerror or e}: {e.filename or ''}".rstrip(": "), file=sys.stderr)
        return 2
    except MemoryError:  # a size no check foresaw: still one line, and nothing was written
        print(
            "jaxrbf: error: out of memory; use fewer points or a lower resolution",
            file=sys.stderr,
        )
        return 2
    except KeyboardInterrupt:
        print("jaxrbf: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
