"""`greedy_fit`: greedy centre reduction (Carr et al. 2001, §4), fitting a subset of the constraints.

Maths. Carr, Beatson, Cherrie, Mitchell, Fright, McCallum & Evans (2001), "Reconstruction and
representation of 3D objects with radial basis functions", SIGGRAPH, observe that an interpolant
through every constraint is far more than a surface needs: the RBF weights of densely sampled,
smooth data are mostly redundant. They fit instead through a subset of the constraints and grow it:

1. choose an initial subset S of the N constraints (x_i, h_i), spread evenly over space;
2. fit s(x) = sum_{j in S} w_j phi(|x - x_j|) + p(x) through the constraints in S (eq. 5-6);
3. evaluate the residual e_i = |s(x_i) - h_i| at **all** N constraints;
4. if max_i e_i <= tol, stop: s meets every constraint to within the fitting accuracy `tol`;
5. otherwise add to S some of the points with e_i > tol (the worst first) and go to 2.

The centres of the final model are the points of S, so it is cheaper to store and evaluate than the
full interpolant, and the fit matches the full interpolant when S grows to all N points. Points are
added spread out (the worst of each of `batch` spatially compact cells of the points above `tol`),
since neighbouring points with large residuals usually share one cause, which one new centre among
them fixes.

Every subset fit is `jaxrbf._fit.fit` with `method="dense"` (one global system through the subset:
same kernels, polynomial, smoothing and solvers). The
residual at all N points is the model's blocked evaluation, so memory stays O(block x centres) for
any N. Each round has a new number of centres, so each round compiles a new solve (a few seconds):
the default batch grows with the subset to keep the rounds few.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._constraints import log
from ._errors import InputError
from ._fit import fit, points_and_values
from ._model import RBFModel, n_poly
from ._prepare import find_duplicates, unit_box_transform
from ._schwarz import _kd_leaves
from ._solve import SOLVERS
from .kernels import AbstractKernel

#: Default fitting accuracy as a fraction of max|values| (the offset d for surface constraints).
DEFAULT_TOL = 1e-3
#: Default initial subset: a quarter of the points, at most this many.
DEFAULT_INITIAL = 2000
#: Default batch: this fraction of the current number of centres (at least `MIN_BATCH`).
BATCH_FRACTION = 0.5
MIN_BATCH = 100


class GreedyRound(NamedTuple):
    """One round of `greedy_fit`."""

    centres: int  # centres in this round's fit
    max_residual: float  # max_i |f(x_i) - h_i| over all points
    n_above: int  # points with residual > tol
    solve_residual: float  # relative residual of the subset solve (`RBFModel.residual`)
    seconds: float  # wall time of the round: fit, residuals and choice of new centres


@dataclass(frozen=True, eq=False)
class GreedyReport:
    """What `greedy_fit` did, round by round.

    **Fields:**
    - `rounds`: a `GreedyRound` per fit: `centres`, `max_residual` (on all points), `n_above`
      (points with residual > `tol`), `solve_residual` (of the subset solve), `seconds`.
    - `converged`: every residual of the final model is <= `tol`.
    - `tol`: the absolute tolerance used.
    - `n_points`: the number of constraints.
    - `centre_indices`: (m,) indices into the input points of the final model's centres, sorted.
    - `reason`: why it stopped, in words.
    """

    rounds: tuple[GreedyRound, ...]
    converged: bool
    tol: float
    n_points: int
    centre_indices: np.ndarray
    reason: str

    @property
    def n_centres(self) -> int:
        return self.rounds[-1].centres

    @property
    def max_residual(self) -> float:
        return self.rounds[-1].max_residual

    @property
    def seconds(self) -> float:
        return sum(r.seconds for r in self.rounds)

    def summary(self) -> str:
        """A short human-readable report: a headline and one line per round."""
        state = "converged" if self.converged else "did NOT converge"
        head = (
            f"greedy fit {state}: {self.n_centres:,} centres of {self.n_points:,} points "
            f"({100 * self.n_centres / self.n_points:.1f}%) in {len(self.rounds)} rounds, "
            f"{self.seconds:.1f} s; max residual {self.max_residual:.3g} (tol {self.tol:.3g}); "
            f"{self.reason}"
        )
        lines = [head, "  round  centres  max residual  above tol  solve residual  seconds"]
        for i, r in enumerate(self.rounds, 1):
            lines.append(
                f"  {i:5d}  {r.centres:7,d}  {r.max_residual:12.3e}  {r.n_above:9,d}  "
                f"{r.solve_residual:14.2e}  {r.seconds:7.2f}"
            )
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.summary()


def _positive_int(value, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise InputError(f"`{name}` must be a positive integer, got {value!r}")
    if value < 1:
        raise InputError(f"`{name}` must be a positive integer (>= 1), got {value!r}")
    return int(value)


def _spread(x: np.ndarray, idx: np.ndarray, count: int, score: np.ndarray) -> np.ndarray:
    """`count` of the points `idx`: the one of highest `score` in each of `count` spatially compact
    k-d cells of them (all of them, sorted, when there are no more than `count`)."""
    if count >= len(idx):
        return np.sort(idx)
    cells = _kd_leaves(x, idx, count)
    return np.sort(np.array([c[np.argmax(score[c])] for c in cells], dtype=np.int64))


def _initial_subset(initial, x: np.ndarray, h: np.ndarray, k: int, rng) -> np.ndarray:
    n = len(x)
    if initial is None or isinstance(initial, int | np.integer) and not isinstance(initial, bool):
        size = (
            min(n, max(min(DEFAULT_INITIAL, n // 4), 2 * (k + 1)))
            if initial is None
            else _positive_int(initial, "initial")
        )
        if size <= k:
            raise InputError(
                f"`initial` = {size} centres cannot determine the {k} polynomial terms plus "
                f"weights; give more than {k}"
            )
        if size > n:
            raise InputError(f"`initial` = {size:,} is more than the {n:,} points")
        subset = _spread(x, np.arange(n), size, rng.random(n))  # a random one per cell
        if not np.any(h[subset] != 0):
            # all on-surface points: the fit would be f = 0; swap one for a point with h != 0
            subset[-1] = int(np.argmax(np.abs(h)))
            subset = np.unique(subset)
        return subset
    sel = np.asarray(initial)
    if sel.ndim != 1 or not np.issubdtype(sel.dtype, np.integer):
        raise InputError(
            "`initial` must be a number of points or a 1-D array of point indices, got "
            f"{type(initial).__name__} of shape {sel.shape} and dtype {sel.dtype}"
        )
    if len(sel) and (sel.min() < 0 or sel.max() >= n):
        raise InputError(f"`initial` holds indices outside [0, {n}): {sel.min()} .. {sel.max()}")
    if len(np.unique(sel)) != len(sel):
        raise InputError(f"`initial` repeats {len(sel) - len(np.unique(sel))} indices")
    if len(sel) <= k:
        raise InputError(
            f"`initial` holds {len(sel)} indices, too few for the {k} polynomial terms plus "
            f"weights; give more than {k}"
        )
    if not np.any(h[sel] != 0):
        raise InputError(
            "every point in `initial` has value 0, so its fit is f = 0; include off-surface "
            "points (value != 0)"
        )
    return np.sort(sel.astype(np.int64))


def greedy_fit(
    points,
    values=None,
    *,
    kernel: str | AbstractKernel = "cubic",
    degree: int = 1,
    smoothing: float = 0.0,
    radius: float | None = None,
    tol: float | None = None,
    initial=None,
    batch: int | None = None,
    max_centres: int | None = None,
    max_rounds: int = 50,
    solver: str = "cg",
    seed: int = 0,
    verbose: bool = False,
) -> tuple[RBFModel, GreedyReport]:
    """Fit an RBF through a greedily grown subset of the constraints until it meets all of them to
    within `tol` (Carr et al. 2001, "Reconstruction and representation of 3D objects with radial
    basis functions", SIGGRAPH; see the module docstring for the algorithm).

    Start from `initial` points spread evenly over space; each round fits through the current
    centres with `jaxrbf.fit`, evaluates |f(x_i) - h_i| at all points, and adds up to `batch` of
    the points above `tol` (the worst of each of `batch` spatially compact cells of them). It stops
    when every residual is <= `tol` (converged), or when `max_centres` or `max_rounds` is reached,
    or when every point above `tol` is a centre already (the solve's accuracy or `smoothing` limit
    it). Stopping unconverged is not an error: the report says so, and the caller decides.

    **Arguments:**
    - `points`: (n, d) array, or a `Constraints` (then `values` must be None).
    - `values`: (n,) values at the points.
    - `kernel`, `degree`, `smoothing`, `radius`, `solver`: as for `jaxrbf.fit`, which fits every
      subset (`solver` defaults to `cg` here).
    - `tol`: the absolute fitting accuracy, in the values' units; default
      `1e-3 * max|values|`, i.e. a thousandth of the off-surface offset d for surface constraints
      (`Constraints` have values 0 and +/- d).
    - `initial`: the first subset: a number of points, chosen one per cell of a k-d split of all
      points (a random member of each, from `seed`), or a 1-D array of point indices. Default:
      min(n, max(min(2000, n // 4), 2 (k + 1))) points, k the number of polynomial terms.
    - `batch`: at most this many points are added per round. Default: half the current number of
      centres, at least 100, so the subset grows geometrically and the rounds stay few.
    - `max_centres`: stop once the model has this many centres (default n; larger values mean n).
    - `max_rounds`: at most this many fits.
    - `seed`: for the random choice of the initial points within their cells.
    - `verbose`: log one line per round, and the outcome, to stderr.

    **Returns:** `(model, report)`: the last round's `RBFModel`, whose centres are the points
    `report.centre_indices` and whose `residual` is max_i |f(x_i) - h_i| / max|h| over all n
    points (not only its centres), and a `GreedyReport` (per round: centres, max residual on all points,
    points above `tol`, the solve's residual, seconds; `converged`; `str(report)` summarises it).

    **Raises:** `InputError` for unusable input or options (tol <= 0, batch < 1, max_centres below
    the initial size, ...), and whatever `jaxrbf.fit` raises for a subset (`SolveError` when a
    subset solve fails).
    """
    x, h = points_and_values(points, values)
    if not np.any(h != 0):
        raise InputError(
            "every value is 0, so the only solution is f = 0 (the paper's trivial solution); "
            "add off-surface points, e.g. with Constraints.from_points(points, normals)"
        )
    if solver not in SOLVERS:
        raise InputError(f"unknown solver {solver!r}; expected one of {', '.join(SOLVERS)}")
    if degree not in (-1, 0, 1):
        raise InputError(f"`degree` must be -1 (no polynomial), 0 or 1, got {degree!r}")
    n, dim = x.shape
    k = n_poly(degree, dim)
    if n <= k:
        raise InputError(
            f"{n} points cannot determine a degree-{degree} polynomial in {dim}-D plus weights; "
            f"give more than {k}"
        )
    if tol is None:
        tol = DEFAULT_TOL * float(np.max(np.abs(h)))
    else:
        try:
            tol = float(tol)
        except (TypeError, ValueError):
            raise InputError(f"`tol` must be a positive number, got {tol!r}") from None
        if not (math.isfinite(tol) and tol > 0):
            raise InputError(
                f"`tol` must be a positive, finite distance in the values' units, got {tol!r}"
            )
    if batch is not None:
        batch = _positive_int(batch, "batch")
    max_rounds = _positive_int(max_rounds, "max_rounds")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer):
        raise InputError(f"`seed` must be an integer, got {seed!r}")
    try:
        smooth = float(smoothing)
    except (TypeError, ValueError):
        smooth = -1.0  # let `fit` word the error
    shift, scale = unit_box_transform(x)
    if smooth == 0:
        # Checked once on all points: a subset has a smaller box, so the same relative tolerance
        # there is stricter, and any duplicate a subset fit would refuse is found here.
        dup = find_duplicates((x - shift) / scale, 1e-9)
        if dup.any():
            j = int(np.argmax(dup))
            raise InputError(
                f"`points` has {int(dup.sum())} duplicate points (first: row {j}); an interpolant "
                "cannot take two values at one point: merge them or set smoothing > 0"
            )
    rng = np.random.default_rng(int(seed))
    centres = _initial_subset(initial, x, h, k, rng)
    if max_centres is None:
        max_centres = n
    else:
        max_centres = _positive_int(max_centres, "max_centres")
        if max_centres <= k:
            raise InputError(
                f"`max_centres` = {max_centres} cannot determine the {k} polynomial terms plus "
                f"weights; give more than {k}"
            )
        if max_centres < len(centres):
            raise InputError(
                f"`max_centres` = {max_centres:,} is smaller than the initial subset of "
                f"{len(centres):,} points; raise it or give a smaller `initial`"
            )
        max_centres = min(max_centres, n)

    x_all = jnp.asarray(x)
    is_centre = np.zeros(n, dtype=bool)
    rounds: list[GreedyRound] = []
    converged = False
    reason = f"stopped after max_rounds = {max_rounds} rounds"
    if verbose:
        log(
            f"greedy fit of {n:,} points to tol {tol:.3g}: {len(centres):,} initial centres, "
            f"{solver} solves"
        )
    for r in range(1, max_rounds + 1):
        t0 = time.perf_counter()
        is_centre[centres] = True
        model = fit(
            x[centres],
            h[centres],
            kernel=kernel,
            degree=degree,
            smoothing=smoothing,
            solver=solver,
            radius=radius,
            method="dense",
        )
        resid = np.abs(np.asarray(model(x_all)) - h)
        above = resid > tol
        n_above = int(above.sum())
        m = len(centres)
        new = None
        if n_above == 0:
            converged = True
            reason = "every residual <= tol"
        elif m >= max_centres:
            reason = f"reached max_centres = {max_centres:,}"
        elif r < max_rounds:
            cand = np.flatnonzero(above & ~is_centre)
            if len(cand) == 0:
                reason = (
                    "the points above tol are all centres already: the solve's accuracy"
                    + (" or the smoothing" if smooth > 0 else "")
                    + " limits the residual"
                )
            else:
                size = batch if batch is not None else max(MIN_BATCH, int(BATCH_FRACTION * m))
                size = min(size, max_centres - m)
                new = _spread(x, cand, size, resid)
        rounds.append(
            GreedyRound(
                centres=m,
                max_residual=float(resid.max()),
                n_above=n_above,
                solve_residual=float(model.residual),
                seconds=time.perf_counter() - t0,
            )
        )
        if verbose:
            g = rounds[-1]
            log(
                f"greedy round {r}: {m:,} centres, max residual {g.max_residual:.3g} "
                f"(tol {tol:.3g}), {n_above:,} points above tol, solve residual "
                f"{g.solve_residual:.1e}, {g.seconds:.2f} s"
            )
        if new is None:
            break
        centres = np.union1d(centres, new)
    report = GreedyReport(
        rounds=tuple(rounds),
        converged=converged,
        tol=tol,
        n_points=n,
        centre_indices=centres,
        reason=reason,
    )
    if verbose:
        log(report.summary().splitlines()[0])
    # As for every `fit`, the model's residual is relative to max|h| at all of its constraints.
    relative = rounds[-1].max_residual / float(np.max(np.abs(h)))
    return eqx.tree_at(lambda mod: mod.residual, model, jnp.asarray(relative)), report
