"""Helpers shared by the benchmarks: paths, thread settings, test data, peak memory, subprocesses
and table printing.

Nothing here imports JAX or jaxrbf at module level, so a worker subprocess that only runs scipy
does not pay for (or measure the memory of) JAX.
"""

from __future__ import annotations

import json
import os
import platform
import resource
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

#: The repository root (the folder holding `jaxrbf/` and `benchmarks/`).
REPO_ROOT = Path(__file__).resolve().parents[1]
#: The shared test meshes (see its README.md), next to the repository.
DATA_DIR = REPO_ROOT.parent / "shared" / "data"
DEFAULT_MESH = "spot.obj"

#: Environment variables that fix the thread count of OpenBLAS/MKL/OpenMP (numpy, scipy, and the
#: LAPACK that jaxlib calls on CPU). They must be set before those libraries are imported.
_THREAD_VARS = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "BLIS_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "NUMEXPR_NUM_THREADS",
)


def thread_env(threads: int, base: dict[str, str] | None = None) -> dict[str, str]:
    """A copy of the environment with every BLAS/OpenMP thread count set to `threads`, and JAX on
    the CPU (unless JAX_PLATFORMS is already set), for a worker subprocess."""
    env = dict(os.environ if base is None else base)
    for var in _THREAD_VARS:
        env[var] = str(threads)
    env.setdefault("JAX_PLATFORMS", "cpu")
    return env


def ensure_jaxrbf_importable() -> None:
    """Put the repository root on sys.path when jaxrbf is not installed (run from a checkout)."""
    try:
        import jaxrbf  # noqa: F401
    except ModuleNotFoundError:
        sys.path.insert(0, str(REPO_ROOT))


def resolve_mesh(name: str | os.PathLike) -> Path:
    """`name` as a path if it exists, else a file in DATA_DIR; exits with a message if absent."""
    path = Path(name)
    if not path.is_file():
        path = DATA_DIR / name
    if not path.is_file():
        available = sorted(p.name for p in DATA_DIR.glob("*.obj")) if DATA_DIR.is_dir() else []
        sys.exit(
            f"error: mesh {str(name)!r} not found (looked for it as given and in {DATA_DIR}). "
            + (
                f"Available there: {', '.join(available)}."
                if available
                else f"{DATA_DIR} is missing: the shared test meshes are not present on this machine."
            )
        )
    return path


def mesh_constraints(path: Path, surface_points: int, seed: int = 0):
    """Constraints sampled from a triangle mesh: `surface_points` on-surface points with face
    normals, plus one off-surface point each way along the normal (about 3N in all).

    Returns (points (n, 3) float64, values (n,) float64, the jaxrbf `Constraints`)."""
    ensure_jaxrbf_importable()
    import trimesh

    import jaxrbf

    mesh = trimesh.load(path, force="mesh")
    c = jaxrbf.Constraints.from_mesh(mesh.vertices, mesh.faces, points=surface_points, seed=seed)
    points = np.ascontiguousarray(np.asarray(c.points, dtype=np.float64))
    values = np.ascontiguousarray(np.asarray(c.values, dtype=np.float64))
    return points, values, c


def box_queries(points: np.ndarray, n: int, seed: int = 1, pad: float = 0.05) -> np.ndarray:
    """`n` points uniform in the bounding box of `points`, grown by `pad` of its size each way."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    margin = pad * (hi - lo)
    rng = np.random.default_rng(seed)
    return rng.uniform(lo - margin, hi + margin, size=(n, points.shape[1]))


# --- memory -----------------------------------------------------------------------------------


def peak_rss_mib() -> float:
    """Peak resident set size of this process so far, MiB (ru_maxrss: KiB on Linux, bytes on
    macOS)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (2**20 if sys.platform == "darwin" else 2**10)


def current_rss_mib() -> float:
    """Resident set size of this process now, MiB."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    try:
        import psutil

        return psutil.Process().memory_info().rss / 2**20
    except ImportError:
        return float("nan")


# --- timing -----------------------------------------------------------------------------------


def timed(fn: Callable[[], object]) -> tuple[object, float]:
    """(fn(), seconds). `fn` must return host data or block on device work itself."""
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


# --- subprocess workers -----------------------------------------------------------------------


def run_worker(
    script: Path, args: Sequence[str], threads: int, timeout: float | None = None
) -> dict:
    """Run `python script *args` in a fresh process with `threads` BLAS threads and return the JSON
    object it prints as its last line of stdout. Its stderr passes through."""
    cmd = [sys.executable, str(script), *args]
    proc = subprocess.run(
        cmd,
        env=thread_env(threads),
        stdout=subprocess.PIPE,
        text=True,
        timeout=timeout,
        check=False,
    )
    lines = [ln for ln in proc.stdout.splitlines() if ln.strip()]
    if proc.returncode != 0 or not lines:
        raise RuntimeError(
            f"worker {' '.join(args)} failed with exit status {proc.returncode}; "
            f"its output:\n{proc.stdout}"
        )
    return json.loads(lines[-1])


def emit_result(result: dict) -> None:
    """The worker's side of `run_worker`: print `result` as one JSON line."""
    print(json.dumps(result), flush=True)


# --- reporting --------------------------------------------------------------------------------


def machine_info() -> dict:
    info = {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        "numpy": np.__version__,
    }
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    info["cpu"] = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return info


def format_table(headers: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    """A plain-text table, columns right-aligned except the first."""
    cells = [[str(h) for h in headers]] + [[str(c) for c in row] for row in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]

    def line(r):
        pairs = enumerate(zip(r, widths, strict=True))
        return "  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in pairs)

    rule = "  ".join("-" * w for w in widths)
    return "\n".join([line(cells[0]), rule] + [line(r) for r in cells[1:]])


def fmt_rate(x: float) -> str:
    """Points per second, e.g. 1.23M/s."""
    for div, unit in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if abs(x) >= div:
            return f"{x / div:.3g}{unit}/s"
    return f"{x:.3g}/s"


def own_peak_rss_mib() -> float:
    """Peak resident set size of this process's own address space, MiB (VmHWM on Linux).

    Prefer this to `peak_rss_mib` in a worker subprocess: Linux folds the peak of the address
    space a process replaces at exec into its ru_maxrss, and subprocess starts workers with vfork,
    so a worker's ru_maxrss is never below its driver's peak. VmHWM belongs to the new address
    space alone. Falls back to `peak_rss_mib` where /proc is unavailable."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return peak_rss_mib()
