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

from .io import MESH_OUTPUTS as MESH_OUT
from .io import POLYLINE_OUTPUTS as CURVE_OUT


def _fit_options(p: argparse.ArgumentParser) -> None:
    from ._solve import SOLVERS
    from .kernels import KERNELS

    g = p.add_argument_group("fitting")
    g.add_argument(
        "--points",
        type=int,
        help="surface points to use (default: 4000 samples of a mesh; every point of a point "
        "cloud, at most 4000 with --method dense)",
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
        "--kernel", choices=list(KERNELS), help="default: cubic in 3-D, thin-plate in 2-D"
    )
    g.add_argument(
        "--radius",
        type=float,
        help="kernel radius, fraction of the bounding-box diagonal (default 0.1)",
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


def _mesh_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("meshing")
    g.add_argument(
        "--resolution",
        type=int,
        default=128,
        help="grid samples along the longest side (default 128)",
    )
    g.add_argument("--project", action="store_true", help="Newton-project vertices onto f = 0")


def build_parser() -> argparse.ArgumentParser:
    from . import __version__

    parser = argparse.ArgumentParser(
        prog="jaxrbf",
        description="Implicit surfaces from radial basis functions (meshes, point clouds, polylines).",
    )
    parser.add_argument("--version", action="version", version=f"jaxrbf {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    r = sub.add_parser(
        "reconstruct", help="input file -> surface mesh (or curves, for a 2-D polyline)"
    )
    r.add_argument(
        "input",
        nargs="?",
        help="mesh (.obj .ply .stl .off), point cloud with normals (.ply .xyz .npz) or polyline (.csv .npy)",
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


def _check_output(path: str, allowed: tuple[str, ...]) -> None:
    from ._errors import InputError

    ext = os.path.splitext(path)[1].lower()
    if ext not in allowed:
        raise InputError(
            f"output '{path}' has an unsupported format '{ext}'; expected one of {', '.join(allowed)}"
        )
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise InputError(f"the folder of output '{path}' does not exist")


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
        verbose=not args.quiet,
    )


def _write_surface(model, args) -> None:
    from . import io
    from ._constraints import log
    from ._polygonize import contour, polygonize

    t0 = time.perf_counter()
    progress = None if args.quiet else True
    if model.dim == 2:
        curves = contour(model, resolution=max(args.resolution, 2), progress=progress)
        io.write_polylines(args.output, curves)
        what = f"{len(curves)} curves"
    else:
        mesh = polygonize(
            model, resolution=args.resolution, project=args.project, progress=progress
        )
        io.write_mesh(args.output, mesh)
        what = f"{len(mesh.vertices):,} vertices, {len(mesh.faces):,} faces"
    if not args.quiet:
        log(f"wrote {args.output}: {what} ({time.perf_counter() - t0:.1f} s)")


def _out_kinds(source) -> tuple[str, ...]:
    """Allowed output extensions for reconstruct: curves for 2-D input, meshes otherwise."""
    if isinstance(source, tuple) and source[1] is not None:
        return MESH_OUT if source[0].shape[1] == 3 else CURVE_OUT
    ext = os.path.splitext(str(source[0]))[1].lower()
    return CURVE_OUT if ext in (".csv", ".npy") else MESH_OUT


def _run(args) -> int:
    from . import io
    from ._constraints import log
    from ._reconstruct import fit_surface
    from ._serialize import load, save

    if args.command == "reconstruct":
        source = _source(args)
        _check_output(args.output, _out_kinds(source))
        model = fit_surface(source[0], source[1], **_fit_kwargs(args))
        _write_surface(model, args)
    elif args.command == "fit":
        _check_output(args.output, (".npz",))
        source = _source(args)
        model = fit_surface(source[0], source[1], **_fit_kwargs(args))
        save(model, args.output)
        if not args.quiet:
            log(f"wrote {args.output}")
    elif args.command == "mesh":
        model = load(args.model)
        _check_output(args.output, MESH_OUT if model.dim == 3 else CURVE_OUT)
        _write_surface(model, args)
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
    except KeyboardInterrupt:
        print("jaxrbf: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
