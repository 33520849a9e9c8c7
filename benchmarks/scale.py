"""Large inputs: jaxrbf's scalable path against Open3D's screened Poisson and scipy's local RBF.

What it measures. Each input is a point cloud of N points sampled uniformly by area on a mesh from
the shared test data, each with the true normal of its face (`jaxrbf.metrics.sample_surface`,
seed `--seed`); by default the Stanford bunny at N = 10k, 100k and 1M and the fandisk at 100k.
On every input, each method runs in its own fresh worker subprocess (this script with a hidden
`--_worker` flag), which reports its wall time and its peak resident set size (VmHWM, not
ru_maxrss, which a worker inherits from its driver: see `_common.own_peak_rss_mib`; the whole
process, imports included; the rise above the baseline after imports and data loading is shown in
brackets). The driver then compares the mesh each method made with the original mesh:
Chamfer-L1 (in % of the reference's bounding-box diagonal, lower is better) and normal consistency
(NC, 1 is best), `jaxrbf.metrics.evaluate` with the same sample count (`--samples`) and seed
(`--metric-seed`) for every method; and it reports the mesh's size. Sampling alone costs some
Chamfer (about 0.05% of the diagonal at the default 1,000,000 samples, 0.1% at 200,000): each table
ends with this floor, the metrics of the reference against itself re-tessellated.

Methods (`--methods`, all four by default):

- `jaxrbf`: `jaxrbf.fit_surface(points, normals, points=N, method=M, verbose=True)` with
  M = `--jaxrbf-method` (default `auto`, which picks the partition-of-unity path for large inputs;
  `none` leaves the keyword out, for a jaxrbf without it), then
  `jaxrbf.polygonize(model, resolution=R)` with R from `--resolution` (by default 256 at 10k,
  320 at 100k, 640 at 1M: Poisson depth 9 meshes on a 512 grid). Fit and meshing times are
  shown separately; the fit includes building the constraints (jaxrbf's default offset: 1% of
  the diagonal, at most 2 point spacings for the partition method), the membrane caps over the
  input's holes (`jaxrbf.fill_holes`, which the partition method does by default: the bunny is
  open at its base) and JAX's compilation: this is the cold, end-to-end time a user sees. The kernel is `fit_surface`'s default: the
  linear r for the partition method from 50,000 samples on, the cubic r^3 below.
- `poisson8`, `poisson9`: Open3D's screened Poisson reconstruction,
  `TriangleMesh.create_from_point_cloud_poisson(pcd, depth=8 or 9, n_threads=--threads)` on the
  same points and true normals, other parameters at Open3D's defaults, and NO density trimming:
  the low-density surface Poisson adds to close the shape (e.g. the bunny's open base) is kept,
  as jaxrbf's closed zero set also covers it.
- `scipy`: `scipy.interpolate.RBFInterpolator(c, v, neighbors=50, kernel="cubic")` (degree 1) on
  the constraints jaxrbf builds (`jaxrbf.Constraints.from_points(points, normals)`: each point,
  plus one point each way along its normal at 1% of the diagonal, validated), evaluated on a
  regular grid over the constraints' box grown by 5% (as `polygonize` does) at
  `--scipy-resolution` samples along the longest side (default 64), then meshed with
  scikit-image's marching cubes. Its "fit" only builds a KD-tree; the time is in the evaluation,
  which solves one small system per group of grid points. A run longer than `--scipy-timeout`
  seconds (default 900) is killed and shown as "> cap", with the evaluation rate it had reached
  and the total time that rate implies. scipy is skipped above `--scipy-max-size` points
  (default 100,000, so not at 1M). On the fandisk's flat faces some grid points' 50 nearest
  constraints are coplanar and the degree-1 system is singular: scipy raises, and the row says so;
  `--scipy-degree 0` gets past it (scipy warns that cubic wants degree >= 1).

After a table per input come the ratios (jaxrbf's time over Poisson depth 9's and over scipy's,
jaxrbf's Chamfer and NC against Poisson depth 9's) and the issue's targets, each PASS or FAIL
(n/a when the runs it needs were not made):

1. 100k points to a mesh in < 60 s (jaxrbf fit + meshing, every 100k input);
2. 1M points in < 600 s with peak memory < 8 GiB;
3. time(1M) / time(100k) <= 12 (same mesh);
4. Chamfer-L1 and normal consistency at least as good as Poisson depth 9 at every size;
5. faster than RBFInterpolator(neighbors=50) at 100k, both meshed on the same grid: where
   jaxrbf and scipy both run on an input, jaxrbf also runs once on scipy's grid (row
   `jaxrbf@scipy-grid`), and that run is the one timed against scipy (scipy's grid is coarse
   because scipy's evaluation is slow; comparing a 256^3 mesh with a 64^3 one would time
   different work).

Run from the repository root (the shared test data must be present). On 2 cores the Poisson and
scipy rows of the default run take about 4 minutes in all (metrics included), plus jaxrbf's time.

    python benchmarks/scale.py                                  # everything
    python benchmarks/scale.py --methods poisson8 poisson9 scipy --sizes 10k 100k
    python benchmarks/scale.py --meshes stanford-bunny.obj --sizes 1M --methods jaxrbf \\
        --resolution 1M=640 --json scale.json

`--sizes` and `--meshes` given together (or either alone, the other at its default: 10k 100k 1M,
and the bunny and fandisk) run every mesh at every size; with neither, the default four inputs.
Sizes take k and M suffixes. `--resolution` is one R for every size, or SIZE=R pairs
(`--resolution 100k=512 1M=640`). Every worker gets `--threads` BLAS/OpenMP threads (default 2)
and JAX runs on the CPU unless JAX_PLATFORMS says otherwise. Other processes on the machine shift
the timings: the load average at the start is printed with the machine.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import (  # noqa: E402
    current_rss_mib,
    emit_result,
    ensure_jaxrbf_importable,
    format_table,
    machine_info,
    own_peak_rss_mib,
    resolve_mesh,
    run_worker,
)

BUNNY, FANDISK = "stanford-bunny.obj", "fandisk.obj"
DEFAULT_INPUTS = ((BUNNY, 10_000), (BUNNY, 100_000), (BUNNY, 1_000_000), (FANDISK, 100_000))
DEFAULT_MESHES = (BUNNY, FANDISK)
DEFAULT_SIZES = (10_000, 100_000, 1_000_000)
METHODS = ("jaxrbf", "poisson8", "poisson9", "scipy")
#: jaxrbf's meshing resolution by input size (the nearest of these sizes, on a log scale, for
#: sizes not listed), unless --resolution says otherwise.
DEFAULT_RESOLUTION = {10_000: 256, 100_000: 320, 1_000_000: 640}
#: The row of jaxrbf meshed on scipy's grid (made when both run): the time comparison with scipy
#: is between runs that evaluate the same grid.
SAME_GRID = "jaxrbf@scipy-grid"
#: The poisson method the ratios and targets compare against.
POISSON_REF = "poisson9"

#: The issue's targets.
TARGET_100K_S = 60.0
TARGET_1M_S = 600.0
TARGET_1M_MIB = 8 * 1024.0
TARGET_SCALING = 12.0

_CHUNK = 2**15  # scipy's grid is evaluated (and its progress recorded) this many points at a time


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def parse_size(text: str) -> int:
    """'10k' -> 10000, '1M' -> 1000000, '2500' -> 2500."""
    t = text.strip().lower().replace("_", "")
    mult = {"k": 1_000, "m": 1_000_000}.get(t[-1:], 1)
    try:
        value = float(t[:-1] if mult > 1 else t) * mult
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a size: {text!r} (e.g. 100000, 100k, 1M)") from None
    if value < 10 or value != int(value):
        raise argparse.ArgumentTypeError(f"a size must be a whole number >= 10, got {text!r}")
    return int(value)


def fmt_size(n: int) -> str:
    for div, unit in ((1_000_000, "M"), (1_000, "k")):
        if n >= div and n % div == 0:
            return f"{n // div}{unit}"
    return f"{n:,}"


# --- workers (run in fresh subprocesses) ------------------------------------------------------


def _progress_path(out: str) -> Path:
    return Path(out + ".progress.json")


def _worker_jaxrbf(data: dict, args) -> tuple[dict, np.ndarray, np.ndarray]:
    ensure_jaxrbf_importable()
    import jax

    import jaxrbf

    pts, nrm = data["points"], data["normals"]
    base = current_rss_mib()
    kw = {} if args.jaxrbf_method == "none" else {"method": args.jaxrbf_method}
    t0 = time.perf_counter()
    model = jaxrbf.fit_surface(pts, nrm, points=len(pts), verbose=True, **kw)
    jax.block_until_ready(model)
    t_fit = time.perf_counter() - t0
    peak_fit = own_peak_rss_mib()
    mkw = {} if args.narrow_band is None else {"narrow_band": args.narrow_band == "on"}
    t0 = time.perf_counter()
    mesh = jaxrbf.polygonize(model, resolution=args.res, progress=False, **mkw)
    t_mesh = time.perf_counter() - t0
    residual = getattr(model, "residual", None)
    result = {
        "library": f"jaxrbf {jaxrbf.__version__} (jax {jax.__version__}, {jax.default_backend()})",
        "setting": f"R={args.res}"
        + ("" if args.jaxrbf_method == "none" else f", method={args.jaxrbf_method}")
        + ("" if args.narrow_band is None else f", narrow_band={args.narrow_band}"),
        "model": type(model).__name__,
        "residual": None if residual is None else float(np.max(np.asarray(residual))),
        "fit_s": t_fit,
        "mesh_s": t_mesh,
        "total_s": t_fit + t_mesh,
        "baseline_mib": base,
        "peak_fit_mib": peak_fit,
    }
    return result, mesh.vertices, mesh.faces


def _worker_poisson(data: dict, args, depth: int) -> tuple[dict, np.ndarray, np.ndarray]:
    import open3d as o3d

    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    pts, nrm = data["points"], data["normals"]
    base = current_rss_mib()
    t0 = time.perf_counter()
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pcd.normals = o3d.utility.Vector3dVector(nrm)
    mesh, _densities = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
        pcd, depth=depth, n_threads=args.threads
    )
    t = time.perf_counter() - t0
    result = {
        "library": f"open3d {o3d.__version__}",
        "setting": f"depth {depth}, untrimmed",
        "fit_s": None,
        "mesh_s": None,
        "total_s": t,
        "baseline_mib": base,
    }
    return result, np.asarray(mesh.vertices), np.asarray(mesh.triangles)


def _worker_scipy(data: dict, args) -> tuple[dict, np.ndarray, np.ndarray]:
    import scipy
    import skimage
    from scipy.interpolate import RBFInterpolator
    from skimage.measure import marching_cubes

    cp, cv = data["c_points"], data["c_values"]
    progress = _progress_path(args.out)
    base = current_rss_mib()
    t0 = time.perf_counter()
    interp = RBFInterpolator(
        cp, cv, neighbors=args.scipy_neighbors, kernel=args.scipy_kernel, degree=args.scipy_degree
    )
    t_fit = time.perf_counter() - t0
    peak_fit = own_peak_rss_mib()

    lo, hi = cp.min(axis=0), cp.max(axis=0)
    pad = 0.05 * (hi - lo).max()
    lo, hi = lo - pad, hi + pad
    h = (hi - lo).max() / (args.res - 1)
    shape = tuple(int(np.ceil(e / h)) + 1 for e in hi - lo)
    total = int(np.prod(shape))
    vol = np.empty(total)
    t0 = time.perf_counter()
    for start in range(0, total, _CHUNK):
        end = min(start + _CHUNK, total)
        ijk = np.stack(np.unravel_index(np.arange(start, end), shape), axis=1)
        vol[start:end] = interp(lo + ijk * h)
        done = {"fit_s": t_fit, "done": end, "total": total, "eval_s": time.perf_counter() - t0}
        partial = progress.with_suffix(".tmp")
        partial.write_text(json.dumps(done))
        os.replace(partial, progress)  # whole, whenever the driver reads it
    t_eval = time.perf_counter() - t0
    vol = vol.reshape(shape)
    if not vol.min() < 0.0 < vol.max():
        raise RuntimeError(
            f"the interpolant never crosses 0 on the grid ({vol.min()}..{vol.max()})"
        )
    t0 = time.perf_counter()
    verts, faces, _, _ = marching_cubes(vol, 0.0, spacing=(h, h, h), allow_degenerate=False)
    t_mc = time.perf_counter() - t0
    result = {
        "library": f"scipy {scipy.__version__}, scikit-image {skimage.__version__}",
        "setting": f"grid {args.res} ({total / 1e3:.0f}k pts, {total / t_eval / 1e3:.1f}k/s), "
        f"{args.scipy_kernel}, degree {args.scipy_degree}, k={args.scipy_neighbors}",
        "constraints": len(cp),
        "grid_points": total,
        "eval_s": t_eval,
        "eval_rate": total / t_eval,
        "marching_cubes_s": t_mc,
        "fit_s": t_fit,
        "mesh_s": t_eval + t_mc,
        "total_s": t_fit + t_eval + t_mc,
        "baseline_mib": base,
        "peak_fit_mib": peak_fit,
    }
    return result, verts + lo, faces


def worker_main(args: argparse.Namespace) -> None:
    try:
        with np.load(args.data) as npz:
            data = {k: npz[k] for k in npz.files}
        if args.worker == "jaxrbf":
            result, verts, faces = _worker_jaxrbf(data, args)
        elif args.worker.startswith("poisson"):
            result, verts, faces = _worker_poisson(data, args, int(args.worker[len("poisson") :]))
        else:
            result, verts, faces = _worker_scipy(data, args)
    except Exception as exc:  # reported as the method's row instead of stopping the benchmark
        traceback.print_exc()
        detail = f"{type(exc).__name__}: {exc}"
        error = detail
        if "full column rank" in detail:
            error = "singular local system: coplanar neighbourhood (--scipy-degree 0 gets past it)"
        emit_result({"status": "error", "error": error, "detail": detail})
        return
    np.savez(args.out, vertices=np.asarray(verts, np.float64), faces=np.asarray(faces, np.int64))
    result.update(status="ok", peak_mib=own_peak_rss_mib(), vertices=len(verts), faces=len(faces))
    emit_result(result)


# --- driver -----------------------------------------------------------------------------------


def resolution_for(args, n: int) -> int:
    if n in args.resolution:
        return args.resolution[n]
    if None in args.resolution:
        return args.resolution[None]
    table = {**DEFAULT_RESOLUTION, **{k: v for k, v in args.resolution.items() if k is not None}}
    return table[min(table, key=lambda s: abs(np.log(s / n)))]


def run_method(args, method: str, data: Path, out: Path, res: int) -> dict:
    """One worker: its result, or a row that says why there is none (timeout, error)."""
    cap = args.scipy_timeout if method == "scipy" else args.timeout
    argv = ["--_worker", method, "--_data", str(data), "--_out", str(out), "--_res", str(res)]
    argv += ["--threads", str(args.threads), "--jaxrbf-method", args.jaxrbf_method]
    argv += ["--scipy-neighbors", str(args.scipy_neighbors), "--scipy-kernel", args.scipy_kernel]
    argv += ["--scipy-degree", str(args.scipy_degree)]
    if args.narrow_band is not None:
        argv += ["--narrow-band", args.narrow_band]
    me = Path(__file__).resolve()
    t0 = time.perf_counter()
    try:
        res = run_worker(me, argv, args.threads, timeout=cap)
    except subprocess.TimeoutExpired:
        res = {"status": "timeout", "cap_s": cap, "elapsed_s": time.perf_counter() - t0}
        progress = _progress_path(str(out))
        if progress.is_file():
            p = json.loads(progress.read_text())
            rate = p["done"] / p["eval_s"] if p["eval_s"] > 0 else float("nan")
            res.update(
                grid_done=p["done"],
                grid_points=p["total"],
                eval_rate=rate,
                estimated_total_s=p["fit_s"] + p["total"] / rate,
            )
    except RuntimeError as exc:  # killed (e.g. out of memory) or crashed before reporting
        res = {"status": "error", "error": str(exc).splitlines()[0]}
    res["wall_s"] = time.perf_counter() - t0
    return res


def subdivided(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The same surface, each triangle split in four at its edge midpoints (midpoints are not
    shared between faces: the metrics only sample the triangles)."""
    a, b, c = (faces[:, k] for k in range(3))
    m = len(faces)
    mids = [(vertices[a] + vertices[b]) / 2, (vertices[b] + vertices[c]) / 2]
    mids.append((vertices[c] + vertices[a]) / 2)
    v = np.concatenate([vertices, *mids])
    ab, bc, ca = (len(vertices) + k * m + np.arange(m) for k in range(3))
    f = np.concatenate([np.stack(t, axis=1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c))])
    return v, np.concatenate([f, np.stack((ab, bc, ca), axis=1)])


def metric_floor(args, ref) -> dict:
    """The metrics between the reference and itself re-tessellated: what sampling alone costs at
    this sample count (the best any reconstruction can score)."""
    import jaxrbf

    copy = jaxrbf.io.Mesh(*subdivided(ref.vertices, ref.faces))
    return jaxrbf.metrics.evaluate(copy, ref, n=args.samples, seed=args.metric_seed)


def _run_scored(args, method, data, out, ref, tag, n, res=None) -> dict:
    """One worker run (at resolution `res`, default scipy's grid) and its mesh's metrics."""
    import jaxrbf

    res = args.scipy_resolution if res is None or method == "scipy" else res
    r = run_method(args, method, data, out, res)
    name = tag.replace("_", " ")
    if r["status"] == "ok":
        with np.load(out) as z:
            mesh = jaxrbf.io.Mesh(z["vertices"], z["faces"])
        t0 = time.perf_counter()
        if len(mesh.faces):
            r.update(jaxrbf.metrics.evaluate(mesh, ref, n=args.samples, seed=args.metric_seed))
        else:
            r.update(status="error", error="empty mesh")
        _log(f"[{name}] {method} at R={res}: metrics in {time.perf_counter() - t0:.1f} s")
        out.unlink()
    _log(f"[{name}] {method} at R={res}: {_status_line(r)}")
    return r


def bench_input(args, mesh_name: str, n: int, tmp: Path) -> dict:
    import jaxrbf

    path = resolve_mesh(mesh_name)
    ref = jaxrbf.io.read_mesh(path)
    pts, nrm = jaxrbf.metrics.sample_surface(ref, n, seed=args.seed)
    tag = f"{path.stem}_{n}"
    data = tmp / f"{tag}.npz"
    arrays = {"points": pts, "normals": nrm}
    res = resolution_for(args, n)
    methods = list(args.methods)
    skipped = {}
    if "scipy" in methods and n > args.scipy_max_size:
        methods.remove("scipy")
        skipped["scipy"] = f"skipped: more than {args.scipy_max_size:,} points (--scipy-max-size)"
    if "scipy" in methods:
        c = jaxrbf.Constraints.from_points(pts, nrm)
        arrays.update(c_points=np.asarray(c.points), c_values=np.asarray(c.values))
        _log(f"[{path.name} {fmt_size(n)}] scipy's constraints: {c.report()}")
    np.savez(data, **arrays)
    del arrays
    rows = {}
    for method in args.methods:
        if method in skipped:
            rows[method] = {"status": "skipped", "reason": skipped[method]}
            continue
        out = tmp / f"{tag}_{method}.npz"
        r = _run_scored(args, method, data, out, ref, tag, n, res)
        rows[method] = r
    if "jaxrbf" in methods and "scipy" in methods and res != args.scipy_resolution:
        # the same work as scipy's row: jaxrbf meshed on scipy's grid, for the time comparison
        rows[SAME_GRID] = _run_scored(args, "jaxrbf", data, tmp / f"{tag}_same.npz", ref, tag, n)
    data.unlink()
    return {
        "mesh": path.name,
        "size": n,
        "metric_floor": metric_floor(args, ref),
        "resolution": res,
        "scipy_resolution": args.scipy_resolution,
        "results": rows,
    }


def _status_line(r: dict) -> str:
    if r["status"] == "ok":
        return f"{r['total_s']:.1f} s, peak {r['peak_mib']:.0f} MiB"
    if r["status"] == "timeout":
        return f"killed after {r['cap_s']:.0f} s (cap)"
    return r.get("error") or r.get("reason", "")


# --- reporting --------------------------------------------------------------------------------


def _s(x) -> str:
    return "-" if x is None else f"{x:.1f}" if x >= 10 else f"{x:.2f}"


def _row(method: str, r: dict) -> list[str]:
    if r["status"] == "ok":
        return [
            method,
            _s(r.get("fit_s")),
            _s(r.get("mesh_s")),
            _s(r["total_s"]),
            f"{r['peak_mib']:.0f} (+{r['peak_mib'] - r['baseline_mib']:.0f})",
            f"{r['vertices']:,}",
            f"{r['faces']:,}",
            f"{100 * r['chamfer_l1']:.4f}%",
            f"{r['normal_consistency']:.4f}",
            r["setting"],
        ]
    if r["status"] == "timeout":
        note = f"killed at the {r['cap_s']:.0f} s cap"
        if "eval_rate" in r:
            note += (
                f"; {r['grid_done']:,}/{r['grid_points']:,} grid points at "
                f"{r['eval_rate']:.0f}/s, est. total {r['estimated_total_s']:.0f} s"
            )
        return [method, "", "", f"> {r['cap_s']:.0f}", "", "", "", "", "", note]
    why = r.get("error") or r.get("reason", "")
    if len(why) > 100:  # the whole message is in the JSON output and on stderr
        why = why[:97] + "..."
    return [method, "", "", "", "", "", "", "", "", why]


def _ok(entry: dict, method: str) -> dict | None:
    r = entry["results"].get(method)
    return r if r is not None and r["status"] == "ok" else None


def ratios(entry: dict) -> dict:
    """jaxrbf against Poisson depth 9 and scipy on one input (None where a run is missing)."""
    j, p, s = _ok(entry, "jaxrbf"), _ok(entry, POISSON_REF), entry["results"].get("scipy")
    same = _ok(entry, SAME_GRID)
    out = {"time_vs_poisson9": None, "time_vs_scipy": None, "scipy_timed_out": False}
    out.update(chamfer_vs_poisson9=None, nc_minus_poisson9=None)
    if j and p:
        out["time_vs_poisson9"] = j["total_s"] / p["total_s"]
        out["chamfer_vs_poisson9"] = j["chamfer_l1"] / p["chamfer_l1"]
        out["nc_minus_poisson9"] = j["normal_consistency"] - p["normal_consistency"]
    j = same or j  # against scipy: on scipy's grid where that run exists
    if j and s and s["status"] == "ok":
        out["time_vs_scipy"] = j["total_s"] / s["total_s"]
    elif j and s and s["status"] == "timeout":
        out["time_vs_scipy"] = j["total_s"] / s["cap_s"]  # an upper bound
        out["scipy_timed_out"] = True
    return out


def input_report(entry: dict, args) -> str:
    head = (
        f"{entry['mesh']}, {entry['size']:,} points (seed {args.seed}); jaxrbf R={entry['resolution']}"
        + (f", scipy grid {entry['scipy_resolution']}" if "scipy" in entry["results"] else "")
    )
    rows = [_row(m, r) for m, r in entry["results"].items()]
    headers = ["method", "fit s", "mesh s", "total s", "peak MiB (rise)", "vertices", "faces"]
    headers += ["Chamfer-L1", "NC", "setting"]
    fl = entry["metric_floor"]
    floor = (
        f"sampling floor (the reference against itself re-tessellated, {args.samples:,} samples): "
        f"Chamfer-L1 {100 * fl['chamfer_l1']:.4f}%, NC {fl['normal_consistency']:.4f}"
    )
    return head + "\n" + format_table(headers, rows) + "\n" + floor


def _x(v, upper=False) -> str:
    return "n/a" if v is None else f"{'< ' if upper else ''}{v:.3g}x"


def ratio_table(results: list[dict]) -> str:
    rows = []
    for e in results:
        r = e["ratios"]
        nc = r["nc_minus_poisson9"]
        rows.append(
            [
                f"{e['mesh']} {fmt_size(e['size'])}",
                _x(r["time_vs_poisson9"]),
                _x(r["time_vs_scipy"], upper=r["scipy_timed_out"]),
                _x(r["chamfer_vs_poisson9"]),
                "n/a" if nc is None else f"{nc:+.4f}",
            ]
        )
    headers = ["input", "time jaxrbf/P9", "time jaxrbf/scipy", "Chamfer jaxrbf/P9"]
    return format_table(headers + ["NC jaxrbf-P9"], rows)


def _jaxrbf(e: dict | None) -> tuple[dict | None, str | None]:
    """jaxrbf's row on input `e` if it ran to a mesh, else None and why not (None: not run)."""
    r = None if e is None else e["results"].get("jaxrbf")
    if r is None:
        return None, None
    if r["status"] == "ok":
        return r, None
    if r["status"] == "timeout":
        return None, f"jaxrbf did not finish: killed at the {r['cap_s']:.0f} s cap"
    return None, f"jaxrbf failed: {r.get('error', '')}"


def targets(results: list[dict]) -> list[dict]:
    """The issue's targets: name, measured value (text), verdict (PASS/FAIL/n/a). A jaxrbf run
    that was made but did not produce a mesh (error, out of memory, over the time cap) fails the
    targets that need it; a run that was not made leaves them n/a."""
    out = []

    def add(name, e, ok, value):
        where = "" if e is None else f" ({e['mesh']} {fmt_size(e['size'])})"
        verdict = "n/a" if ok is None else "PASS" if ok else "FAIL"
        out.append({"target": name + where, "verdict": verdict, "value": value})

    def at(size):
        return [e for e in results if e["size"] == size] or [None]

    name = f"100k points to a mesh in < {TARGET_100K_S:g} s"
    for e in at(100_000):
        j, why = _jaxrbf(e)
        if j:
            add(name, e, j["total_s"] < TARGET_100K_S, f"{j['total_s']:.1f} s")
        else:
            add(name, e, False if why else None, why or "no jaxrbf run at 100k")

    name = f"1M points in < {TARGET_1M_S:g} s, peak memory < {TARGET_1M_MIB / 1024:g} GiB"
    for e in at(1_000_000):
        j, why = _jaxrbf(e)
        if j:
            ok = j["total_s"] < TARGET_1M_S and j["peak_mib"] < TARGET_1M_MIB
            add(name, e, ok, f"{j['total_s']:.1f} s, {j['peak_mib'] / 1024:.2f} GiB")
        else:
            add(name, e, False if why else None, why or "no jaxrbf run at 1M")

    name = f"time(1M) / time(100k) <= {TARGET_SCALING:g}"
    pairs = 0
    for e1 in (e for e in results if e["size"] == 1_000_000):
        for e0 in (e for e in results if e["size"] == 100_000 and e["mesh"] == e1["mesh"]):
            (j1, why1), (j0, why0) = _jaxrbf(e1), _jaxrbf(e0)
            pairs += 1
            if j1 and j0:
                q = j1["total_s"] / j0["total_s"]
                add(name, e1, q <= TARGET_SCALING, f"{q:.2f}")
            elif why1 or why0:
                add(name, e1, False, why1 or why0)
            else:
                add(name, e1, None, "no jaxrbf runs")
    if not pairs:
        add(name, None, None, "needs runs at 100k and 1M on the same mesh")

    name = "Chamfer-L1 and NC at least as good as Poisson depth 9"
    for e in results or [None]:
        (j, why), p = _jaxrbf(e), e and _ok(e, POISSON_REF)
        if j and p:
            ok = (
                j["chamfer_l1"] <= p["chamfer_l1"]
                and j["normal_consistency"] >= p["normal_consistency"]
            )
            val = (
                f"Chamfer {100 * j['chamfer_l1']:.4f}% vs {100 * p['chamfer_l1']:.4f}%, "
                f"NC {j['normal_consistency']:.4f} vs {p['normal_consistency']:.4f}"
            )
            add(name, e, ok, val)
        elif why and p:
            add(name, e, False, why)
        else:
            add(name, e, None, f"needs jaxrbf and {POISSON_REF}")

    name = "faster than RBFInterpolator(neighbors=50) at 100k, on the same grid"
    for e in at(100_000):
        (j, why), s = _jaxrbf(e), e and e["results"].get("scipy")
        if j and _ok(e, SAME_GRID):
            j = _ok(e, SAME_GRID)
        if j and s and s["status"] == "ok":
            add(
                name,
                e,
                j["total_s"] < s["total_s"],
                f"{j['total_s']:.1f} s vs {s['total_s']:.1f} s",
            )
        elif j and s and s["status"] == "timeout":
            val = f"{j['total_s']:.1f} s vs > {s['cap_s']:.0f} s (scipy killed at the cap)"
            add(name, e, j["total_s"] < s["cap_s"], val)
        elif why and s and s["status"] in ("ok", "timeout"):
            add(name, e, False, why)
        else:
            add(name, e, None, "needs jaxrbf and scipy")
    return out


def machine_lines() -> tuple[dict, str]:
    info = machine_info()
    try:
        with open("/proc/meminfo") as fh:
            kib = int(next(ln for ln in fh if ln.startswith("MemTotal:")).split()[1])
        info["memory_gib"] = round(kib / 2**20, 1)
    except (OSError, StopIteration, ValueError):
        pass
    try:
        info["loadavg_at_start"] = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        pass
    return info, "machine: " + "; ".join(f"{k} {v}" for k, v in info.items())


def _parse_resolution(items) -> dict:
    out = {}
    for item in items or []:
        size, _, r = item.rpartition("=")
        try:
            res = int(r)
        except ValueError:
            raise SystemExit(f"error: --resolution: not a resolution: {item!r}") from None
        if res < 8:
            raise SystemExit(f"error: --resolution must be at least 8, got {item!r}")
        try:
            out[parse_size(size) if size else None] = res
        except argparse.ArgumentTypeError as exc:
            raise SystemExit(f"error: --resolution: {exc}") from None
    return out


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        description="Time, peak memory and accuracy of jaxrbf's scalable path against Open3D's "
        "screened Poisson and scipy's RBFInterpolator(neighbors=50) at 10k-1M points.",
        epilog="See the module docstring (benchmarks/scale.py) for what each method does.",
    )
    p.add_argument(
        "--sizes",
        type=parse_size,
        nargs="+",
        help="input sizes, e.g. 10k 100k 1M (default: the bunny at 10k 100k 1M, fandisk at 100k)",
    )
    p.add_argument(
        "--meshes",
        nargs="+",
        help=f"mesh files or names in the shared data (default {BUNNY} {FANDISK})",
    )
    p.add_argument(
        "--methods",
        nargs="+",
        choices=METHODS,
        default=list(METHODS),
        help="default: all of " + " ".join(METHODS),
    )
    p.add_argument(
        "--resolution",
        nargs="+",
        metavar="[SIZE=]R",
        help="jaxrbf's meshing resolution: one R for all sizes or SIZE=R pairs (default "
        + ", ".join(f"{fmt_size(k)}={v}" for k, v in DEFAULT_RESOLUTION.items())
        + ")",
    )
    p.add_argument(
        "--jaxrbf-method",
        choices=["auto", "dense", "partition", "global", "none"],
        default="auto",
        help="fit_surface's method= (default auto); none: leave the keyword out",
    )
    p.add_argument(
        "--narrow-band",
        choices=["on", "off"],
        help="polygonize's narrow_band= (default: not passed, the library decides)",
    )
    p.add_argument(
        "--scipy-resolution",
        type=int,
        default=64,
        help="scipy's grid samples along the longest side (default 64)",
    )
    p.add_argument(
        "--scipy-timeout",
        type=float,
        default=900.0,
        help="seconds before a scipy worker is killed (default 900)",
    )
    p.add_argument(
        "--scipy-max-size",
        type=parse_size,
        default=100_000,
        help="skip scipy above this many points (default 100k)",
    )
    p.add_argument("--scipy-neighbors", type=int, default=50, help="default 50")
    p.add_argument(
        "--scipy-kernel",
        choices=["cubic", "thin_plate_spline"],
        default="cubic",
        help="RBFInterpolator's kernel (default cubic, jaxrbf's)",
    )
    p.add_argument(
        "--scipy-degree",
        type=int,
        default=1,
        help="RBFInterpolator's polynomial degree (default 1, its default and jaxrbf's; 0 gets "
        "past neighbourhoods of coplanar constraints, with a warning from scipy)",
    )
    p.add_argument(
        "--timeout",
        type=float,
        default=3600.0,
        help="seconds before a jaxrbf or Poisson worker is killed (default 3600)",
    )
    p.add_argument(
        "--samples",
        type=int,
        default=1_000_000,
        help="surface samples per mesh for Chamfer and NC (default 1000000)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the input sampling (default 0)")
    p.add_argument(
        "--metric-seed", type=int, default=1, help="seed of the metrics' sampling (default 1)"
    )
    p.add_argument("--threads", type=int, default=2, help="BLAS/OpenMP threads (default 2)")
    p.add_argument("--json", type=Path, metavar="PATH", help="also write every figure to PATH")
    p.add_argument("--_worker", dest="worker", choices=METHODS, help=argparse.SUPPRESS)
    p.add_argument("--_data", dest="data", help=argparse.SUPPRESS)
    p.add_argument("--_out", dest="out", help=argparse.SUPPRESS)
    p.add_argument("--_res", dest="res", type=int, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.worker:
        return args
    if min(args.threads, args.samples, args.scipy_neighbors) < 1:
        p.error("--threads, --samples and --scipy-neighbors must be positive")
    if args.scipy_resolution < 8:
        p.error("--scipy-resolution must be at least 8")
    args.resolution = _parse_resolution(args.resolution)
    if args.sizes is None and args.meshes is None:
        args.inputs = list(DEFAULT_INPUTS)
    else:
        meshes, sizes = args.meshes or DEFAULT_MESHES, args.sizes or DEFAULT_SIZES
        args.inputs = [(m, n) for m in meshes for n in sizes]
    args.methods = list(dict.fromkeys(args.methods))
    return args


def main(argv=None) -> None:
    args = parse_args(argv)
    if args.worker:
        worker_main(args)
        return
    for mesh, _ in args.inputs:
        resolve_mesh(mesh)  # fail early, with the message, when the shared data is absent
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    ensure_jaxrbf_importable()
    info, line = machine_lines()
    print(line)
    print(
        f"methods: {' '.join(args.methods)}; {args.threads} threads per worker; metrics: "
        f"{args.samples:,} samples per mesh, seed {args.metric_seed}, distances in % of the "
        "reference's bounding-box diagonal",
        flush=True,
    )
    t_start = time.perf_counter()
    results = []
    with tempfile.TemporaryDirectory(prefix="jaxrbf_scale_") as tmp:
        for mesh, n in args.inputs:
            entry = bench_input(args, mesh, n, Path(tmp))
            entry["ratios"] = ratios(entry)
            results.append(entry)
            print("\n" + input_report(entry, args), flush=True)
    libs = sorted({r["library"] for e in results for r in e["results"].values() if "library" in r})
    tg = targets(results)
    print(
        "\nPeak memory: the worker process's peak RSS, in brackets its rise above the baseline "
        "after imports and data loading. Poisson: Open3D's screened Poisson on the same points "
        "and true normals, no density trimming. jaxrbf's fit time includes building the "
        "constraints and JAX's compilation."
    )
    print("libraries: " + ("; ".join(libs) or "(no worker finished)"))
    print("\nRatios (time: total wall time to a mesh; P9 = Poisson depth 9)")
    print(ratio_table(results))
    print("\nTargets")
    print(
        format_table(
            ["target", "value", "verdict"], [[t["target"], t["value"], t["verdict"]] for t in tg]
        )
    )
    total = time.perf_counter() - t_start
    print(f"\n(total {total:.0f} s)")
    if args.json:
        settings = {
            k: v
            for k, v in vars(args).items()
            if k not in ("worker", "data", "out", "res", "json", "resolution", "inputs")
        }
        settings["resolution"] = {str(k): v for k, v in args.resolution.items()}
        payload = {
            "benchmark": "scale",
            "machine": info,
            "libraries": libs,
            "settings": settings,
            "inputs": [list(i) for i in args.inputs],
            "results": results,
            "targets": tg,
            "total_s": total,
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(payload, indent=2, default=str))
        print(f"numbers written to {args.json}")


if __name__ == "__main__":
    main()
