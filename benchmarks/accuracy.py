"""Accuracy of jaxrbf's dense reconstruction on real meshes.

For the bunny, spot and fandisk, sampled with 2,000 and 4,000 points on the faces (face normals),
this fits the cubic kernel with the default offset (1% of the diagonal), meshes the zero set at
resolution 128, and prints Chamfer-L1, Hausdorff, normal consistency and F-score (at 1% of the
diagonal) against the original mesh, distances in units of its bounding-box diagonal.

Target (issue 2): Chamfer-L1 below 0.4% of the diagonal on spot and the bunny at resolution 128.

Run: python benchmarks/accuracy.py [--meshes stanford-bunny.obj spot.obj fandisk.obj]
     [--sizes 2000 4000] [--resolution 128] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from _common import ensure_jaxrbf_importable, format_table, machine_info, resolve_mesh

TARGET = 0.004
TARGET_MESHES = ("stanford-bunny.obj", "spot.obj")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--meshes", nargs="+", default=["stanford-bunny.obj", "spot.obj", "fandisk.obj"]
    )
    ap.add_argument("--sizes", nargs="+", type=int, default=[2000, 4000])
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument(
        "--samples", type=int, default=200_000, help="surface samples per mesh for the metrics"
    )
    ap.add_argument("--json", help="write the figures to this file")
    args = ap.parse_args()

    ensure_jaxrbf_importable()
    import jaxrbf

    rows, results = [], []
    for name in args.meshes:
        path = resolve_mesh(name)
        ref = jaxrbf.io.read_mesh(path)
        for n in args.sizes:
            t0 = time.perf_counter()
            model = jaxrbf.fit_surface(str(path), points=n)
            t_fit = time.perf_counter() - t0
            t0 = time.perf_counter()
            mesh = jaxrbf.polygonize(model, resolution=args.resolution, progress=False)
            t_mesh = time.perf_counter() - t0
            m = jaxrbf.metrics.evaluate(mesh, ref, n=args.samples)
            target = TARGET if name in TARGET_MESHES else None
            verdict = "" if target is None else ("PASS" if m["chamfer_l1"] < target else "FAIL")
            results.append(
                dict(
                    mesh=name,
                    points=n,
                    fit_s=t_fit,
                    mesh_s=t_mesh,
                    residual=float(model.residual),
                    **m,
                    verdict=verdict,
                )
            )
            rows.append(
                [
                    name,
                    n,
                    f"{t_fit:.1f}",
                    f"{t_mesh:.1f}",
                    f"{float(model.residual):.1e}",
                    f"{100 * m['chamfer_l1']:.3f}%",
                    f"{100 * m['hausdorff']:.2f}%",
                    f"{m['normal_consistency']:.4f}",
                    f"{m['f_score']:.4f}",
                    verdict,
                ]
            )
            print(f"{name} {n}: done", file=sys.stderr, flush=True)
    print(
        f"jaxrbf {jaxrbf.__version__}, resolution {args.resolution}, cubic kernel, offset 1% of the "
        f"diagonal; distances in % of the reference's bounding-box diagonal"
    )
    print(
        format_table(
            [
                "mesh",
                "points",
                "fit s",
                "mesh s",
                "residual",
                "chamfer-L1",
                "hausdorff",
                "normal cons.",
                "F@1%",
                f"chamfer < {100 * TARGET:.1f}%",
            ],
            rows,
        )
    )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(dict(machine=machine_info(), results=results), fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
