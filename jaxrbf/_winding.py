"""Inside and outside without a watertight input: the fast winding number of oriented points, and
the volume constraints it values.

An RBF fit knows the surface only near its samples. Away from them, the sign of f is whatever
the interpolant's extrapolation gives, and wherever an input is open, has holes or comes in
pieces, the zero set grows balloons and sheets there. The generalised winding number answers
"inside or outside?" for any oriented sample set, open or closed (Jacobson, Kavan &
Sorkine-Hornung 2013); for oriented points with area weights a_i it is (Barill et al. 2018)

    w(q) = sum_i a_i (p_i - q) . n_i / (4 pi |p_i - q|^3),

about 1 inside a closed surface, 0 outside, and smooth (harmonic) across holes and open
boundaries, where it passes through 1/2.

- **Evaluation** (`winding_number`): a k-d split of the samples into leaves of about
  `LEAF_SIZE` samples, grouped by `GROUP` into subtrees; a node (group or leaf) farther from the
  query than `BETA` times its radius counts as one dipole at its centroid (the sum of its
  a_i n_i), the leaves of a near group are tested in turn, and a near leaf is summed exactly (a
  two-level Barnes-Hut sum). jit-compiled in float32 over fixed blocks of queries: only the sign of w - 1/2 is used,
  and far from 1/2; the far-field approximation errs by a few hundredths at most where it is
  used (measured in the tests against the direct sum).
- **Area weights** (`calibrated_areas`): pi r_8^2 / 8 per sample (`sample_areas`), halved on
  the boundaries of the sampled surface (a rim sample's neighbours fill a half-disc), then
  divided by the jump of w across the surface extrapolated to zero distance (`unit_jump`:
  exactly 1 for exact weights, on any surface), so that w is 1/2 on a hole's closing surface
  whatever the sampling.
- **Volume constraints** (`volume_constraints`): probe points on an octree that refines towards
  the samples, kept in shells at 1.5 to 3 cell sizes from the nearest sample (so their density
  follows the distance: fine near the data, coarse far away), the cells where w is near 1/2
  refined down to the finest size, and a finer lattice around the samples on the surface's
  boundaries (`rim_probes`: where the data stop, the octree's shells start too far out), and a
  sparse shell 4.5 spacings off the surface on both sides (`shell_probes`: between the
  off-surface points and the octree's finest shell, where nothing else holds the fit). Each
  is valued by `signed_values`: positive outside (w below the closing level), negative inside,
  in magnitude the smaller of its distance to the samples and its first-order distance to that
  level.
- **Closing level** (`closing_level`): the level of w that the surface itself stands on, the
  mid-value of w read a few spacings along and against the normals, carried between samples
  as a local median and clipped to [1/2, 0.7]. It is 1/2 on a closed surface; around a pocket
  that no view of a scan reached it is higher, and a closing on it recedes into the pocket
  the way the surface around it does instead of spanning its mouth. Never below 1/2: at the
  rim of a hole in a convex part the mid-value is lower, and a closing there would bulge out.
  The values continue the off-surface constraints (+/-d at distance d), so f stays close to a
  signed distance everywhere, and over holes and past open boundaries the fit crosses zero
  where the winding number does, with the same unit slope.
"""

from __future__ import annotations

import warnings
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial import cKDTree

from ._errors import InputError
from ._holes import boundary_mask, rim_groups, tangent_frames, widest_gap
from ._project import _newton_step
from ._schwarz import _kd_leaves
from .objectives import point_spacing

#: Samples per leaf of the evaluation tree (about), and leaves per group.
LEAF_SIZE = 24
GROUP = 16
#: A leaf farther than this many times its radius from a query counts as one dipole.
BETA = 2.0
#: Queries per compiled block.
BLOCK = 512
#: Neighbours behind each sample's area weight pi r_k^2 / k (r_k: distance to the k-th).
AREA_NEIGHBOURS = 8
#: Finest probe cell, in median sample spacings; probes keep 1.5 to 3 cells from every sample.
PROBE_CELL_SPACINGS = 6.0
#: At most about this many probes: past it (about 200,000 samples) the finest cell grows, so
#: that the winding number's cost stays bounded (its shell still lies beyond the reach of the
#: partition's finest patches, a few spacings).
MAX_PROBES = 100_000
SHELL = (1.5, 3.0)
#: Probes fill the samples' box grown by this fraction of its largest side on every side: past
#: the meshing box (the samples' box grown by 5%), so that f has their sign all over it.
PROBE_PADDING = 0.1
#: The coarsest probe cell is at least this fraction of the box's largest side.
COARSEST_CELL = 1 / 6
#: Octree cells whose probe has |w - 1/2| < RAMP (over a hole, past an open boundary) are
#: refined down to the finest cell.
RAMP = 0.2
#: Area weights are calibrated by the jump of w across the surface (`unit_jump`), measured
#: this many spacings (and twice as many) off the surface at up to this many samples.
JUMP_SPACINGS = 4.0
JUMP_SAMPLES = 2000
#: `unit_jump` needs this many samples whose readings cross no other face, of JUMP_TRIED x
#: JUMP_SAMPLES tried.
JUMP_MIN_CLEAR, JUMP_TRIED = 50, 8
#: Rim probes (`rim_probes`): a lattice of RIM_CELL spacings around the boundary samples, out to
#: RIM_REACH spacings (or the octree's inner shell, if nearer), RIM_SHELL steps from every sample.
RIM_CELL = 2.0
RIM_REACH = 9.0
RIM_SHELL = 1.5
#: Shell probes (`shell_probes`): NEAR_SPACINGS out along and against the normal of one sample
#: per cell of NEAR_SPACINGS, kept where no sample is nearer than NEAR_CLEAR of that distance,
#: then one per cell of 1.5 times that size.
NEAR_SPACINGS = 4.5
NEAR_CLEAR = 0.75
#: Closing samples (`closing_samples`): the level w = 1/2 is sampled once per cell of a lattice
#: of CLOSE_CELL spacings, wherever it lies at least CLOSE_CLEAR spacings from every sample,
#: grown from the undecided probes (at most CLOSE_MAX_CELLS cells looked at).
CLOSE_CELL = 2.0
CLOSE_CLEAR = 3.0
CLOSE_MAX_CELLS = 2_000_000
#: A sample is buried when w reads above `BURIED_LEVEL` at `BURIED_SPACINGS` spacings along its
#: normal and as far against it (`buried_samples`).
BURIED_SPACINGS, BURIED_LEVEL = 4.0, 0.6
#: ... unless a face turned back towards the sample lies nearer than that (more than
#: `BURIED_GAP` spacings ahead; nearer, the two touch, as boards that meet face to face, whose
#: seam lies inside their union): then w is read halfway to it.
BURIED_GAP = 1.0
#: From those, the walls are followed to the seam: a sample within `BURIED_SPACINGS` spacings
#: of a buried one is buried when its own w reads above SEAM_LEVEL (`_buried_to_the_seam`).
SEAM_LEVEL = 0.9
#: `buried_samples` tests every sample up to this many, a random subset of this many beyond
#: (then grows from those found buried).
BURIED_TESTED = 200_000
#: `contradicted` judges every off-surface point up to this many (100,000 samples), a random
#: subset of this many beyond (then grows from those found).
CONTRADICTED_TESTED = 200_000
#: `points_inward` reads w at this many samples at most (the median of a random subset), and
#: calls the normals inward when that median is below -ORIENT_LEVEL. A flat open sheet reads 0
#: (it has no inside); the least closed of the test inputs, the beetle's open car body, reads
#: 0.23 (a closed surface about 0.47, an open hemisphere 0.32).
ORIENT_TESTED, ORIENT_LEVEL = 20_000, 0.1
#: The closing level (`closing_level`): w's mid-value across the surface, read `JUMP_SPACINGS`
#: along and against the normals of up to LEVEL_SAMPLES samples whose two readings are clear of
#: other samples, carried between them as the median of the LEVEL_NEIGHBOURS nearest, clipped
#: to LEVEL_CLIP.
LEVEL_SAMPLES = 20_000
LEVEL_NEIGHBOURS = 128
LEVEL_CLIP = (0.5, 0.7)
#: Open shells (`shell_samples`): pieces (samples linked by their SHELL_LINK_K nearest within
#: SHELL_LINK spacings) of at least SHELL_MIN_SAMPLES samples, read JUMP_SPACINGS along and
#: against the normals of up to SHELL_TESTED of them, whose median jump across them is above
#: SHELL_JUMP (a thin closed plate, both of whose readings fall outside it, jumps by about 0,
#: where a sheet jumps by 1) and whose median mid-value of w is below SHELL_LEVEL in magnitude,
#: or below SHELL_OPENING_LEVEL with openings that span SHELL_OPENING of the piece's area or
#: more (`openings`: the rims' convex hulls in their planes, against the samples' areas).
#: The mid-value grows with how much of a closed surface a piece is: a flat sheet 0, a
#: 30-degree cap 0.11, an open hemisphere 0.31-0.33 (1k-100k samples), a sphere with 40% of
#: its area cut away 0.35, 30% 0.39-0.40, 20% 0.42-0.43, 10% 0.45-0.47, a closed surface 1/2
#: (0.47-0.50 on the test meshes); it drifts up by about 0.02 from 10k to 100k samples, which
#: puts a level between a 10% and a 20% opening at the mercy of the sample count. The rims'
#: hulls measure the opening itself, to within 0.01 from 1k to 100k samples (0.21 / 0.20 of
#: the area for 20% cut away, 0.11 / 0.10 for 10%), but cannot tell an opening that another
#: piece covers (the teapot's lid over its body: hulls 0.11, mid-value 0.48-0.54), which the
#: mid-value does. SHELL_LEVEL = 1/3: no more than half a closed surface is open whatever its
#: rims say (a car body whose face normals disagree has ragged rims). SHELL_OPENING = 0.15,
#: SHELL_OPENING_LEVEL = 0.46: an opening of 15% of the piece or more, not covered, is kept
#: open, thickened; smaller holes are closed across (the holed spot's 12 holes: 0.08, 0.44).
#: Closing invents a lid as large as the opening, all of it far from a surface that is open:
#: measured against their input (10k samples with true normals, Chamfer-L1 / NC / precision
#: at 0.5%), a sphere with 20% cut away closed came out at 0.78% / 0.964 / 84% and a cap of
#: 115 degrees 1.15% / 0.932 / 78%, where Open3D's Poisson, which leaves such an opening open
#: (its surface runs on to its box), gives 0.42% / 0.997 / 88% and 0.74% / 0.994 / 81%;
#: thickened they measure 0.13% / 0.999 / 99.8-99.9%. A sphere with 10% cut away is still
#: closed (0.38% / 0.990 / 91%, Poisson's stub 0.22% / 0.996 / 94%): a hole of that size is
#: one a user expects closed.
SHELL_LINK, SHELL_LINK_K = 4.0, 12
SHELL_MIN_SAMPLES, SHELL_TESTED = 100, 256
#: Pieces of SHELL_SMALL to SHELL_MIN_SAMPLES samples are read too, and judged when the jump
#: across them is above SHELL_JUMP / 2 (open discs of 80-95 samples beside a sphere of 3,000
#: read 0.41-0.57); below, or unclear, they go with the nearest piece that was judged (a gap
#: in the sampling, or a piece too small to read). On a made soup of a closed sphere and
#: 40 small pieces (caps, sheets, short tubes, blobs; 10k samples, true normals), reading
#: them took Chamfer-L1 / NC / precision from 0.131% / 0.965 / 95.2% to 0.107% / 0.974 /
#: 97.8% (Poisson 0.414% / 0.924 / 72.4%): a small open piece beside a closed one had taken
#: the closed one's side and was closed into a balloon.
SHELL_SMALL = 30
SHELL_LEVEL, SHELL_JUMP = 1 / 3, 0.5
SHELL_OPENING, SHELL_OPENING_LEVEL = 0.15, 0.46
#: A thin closed part (a board, a seat, a blade: 4-12 spacings thick) is no open sheet, whatever
#: w reads across it: its readings against the normal land by its other face, where the sum
#: over discrete samples reads neither inside nor outside (mid-values 0.29-0.35 on made boxes
#: 4-9 spacings thick, against a sheet's 0 and the level SHELL_LEVEL = 1/3). A piece is one
#: when at least BACKED_SHARE of its read samples are backed: going against the normal, within
#: BACKED_SPACINGS spacings, a sample within BACKED_WAY spacings of the way faces the other
#: way (cosine below -1/2; `_backed`). An open sheet has nothing behind it, or a surface that
#: faces it.
BACKED_SPACINGS, BACKED_SHARE = 12, 0.5
#: ... of the way: random samples leave gaps of 2-3 spacings on the other face.
BACKED_WAY, BACKED_NEIGHBOURS = 3.0, 4
#: `openings`' rims: groups of RIM_MIN boundary samples or more (`rim_groups`; a short tube of
#: 100 samples has 5-10 at each end).
RIM_MIN = 5
#: The level for a noisy cloud (a scan, which the fit approximates): there an opening is most
#: often a part of a closed object that no view saw (a sole, an underside, a pocket), which the
#: user wants closed, and noise lifts the mid-value by about 0.015 (20k samples with 0.25% of
#: the diagonal of noise). A scan is thickened only where it reads nearer a sheet (0) than a
#: closed surface (1/2): a terrain, a facade, a single view. Measured with scanners' or
#: estimated normals: the virtual scans of closed meshes 0.475-0.490, the real scanned leg
#: 0.33 (a closed object seen from too few sides: closed), a noisy terrain 0.00. That terrain
#: (20k samples, 0.25% noise, true normals), closed, came out at Chamfer-L1 0.57% / NC 0.919 /
#: precision 45% against Poisson's 0.27% / 0.974 / 84%; thickened, 0.11% / 0.993 / 99.9%.
SHELL_LEVEL_NOISY = 0.25
#: Two-faced samples (`two_faced`): at least TWO_FACED_PAIRS of a sample's TWO_FACED_K nearest
#: within TWO_FACED_LINK spacings face the other way (cosine below -1/2) and lie in its tangent
#: plane (less than TWO_FACED_OFFSET spacings off it); a piece more than TWO_FACED_SHARE of whose
#: samples are is an open shell whatever w reads across it.
TWO_FACED_K, TWO_FACED_LINK, TWO_FACED_PAIRS, TWO_FACED_OFFSET = 12, 3.0, 2, 0.1
TWO_FACED_SHARE = 0.5
#: A piece more than MIXED_SHARE of whose samples have TWO_FACED_PAIRS or more neighbours beside
#: them facing the other way (`facing_beside`) has normals that point either way, and their signs
#: are made to agree along the surface before anything reads w (`open_shells(orient=True)`).
#: Measured piece shares on wild.py's inputs with normals: the made wound figure (parts wound
#: inside out, crossing) 0.035, every other oriented input 0.008 or less (the real leg and anchor
#: with Open3D's oriented normals 0.004 and 0, the scanner-normal scans 0.002 and 0), the made
#: cloth figure's piece with its two-faced cloth 0.31 (turned too: Chamfer-L1 0.0965% -> 0.0988%,
#: NC 0.9834 -> 0.9801, Poisson's 0.9836% / 0.8721); normals that point either way in patches
#: (Open3D's `estimate_normals` without orienting them, on the leg and the anchor) 0.16 and 0.12,
#: at random 0.80. Those patches had read as open sheets and come out as thin slabs, two surfaces
#: a spacing apart where the scan was of a solid.
MIXED_SHARE = 0.08
#: A two-faced sheet within a piece (hanging on a closed part) is one of TWO_FACED_PART of the
#: samples or more (and SHELL_MIN_SAMPLES): where two closed parts touch face to face (the
#: contact's samples face both ways too) the patch holds few, but as many more as the sampling
#: is denser (suzanne's largest: 18 samples of 100k).
TWO_FACED_PART = 0.005
#: Times a two-faced sheet takes in the samples most of whose neighbours are on it.
TWO_FACED_GROW = 2
#: A flap (`flap_samples`): a sample whose own reading is a sheet's, mid-value below FLAP_LEVEL
#: in magnitude (nearer 0 than 1/3; a closed surface reads 1/2, and by a hole or an opening a
#: tenth of its area, down to 0.3-0.4 in the first percentile of the samples); grouped and grown
#: as the two-faced sheets are (`_sheets_of`).
FLAP_LEVEL = 1 / 6


def sample_areas(points: np.ndarray, k: int = AREA_NEIGHBOURS, tree=None) -> np.ndarray:
    """The area each sample stands for: pi r_k^2 / k, r_k its distance to its k-th nearest
    neighbour (k samples in a disc of that radius), so the weights follow the local density."""
    k = min(k, len(points) - 1)
    if k < 1:
        raise InputError("the winding number needs at least 2 samples")
    tree = cKDTree(points) if tree is None else tree
    dist, _ = tree.query(points, k=k + 1, workers=-1)
    r = np.maximum(dist[:, -1], 1e-300)
    return np.pi * r**2 / k


class WindingTree(NamedTuple):
    """Two levels of the samples' k-d split: leaves of a few dozen samples and groups of `GROUP`
    consecutive leaves (a subtree each). Each node has a centroid, a dipole (the sum of its
    a_i n_i) and a radius; the leaves also list their members (padded with zero weight)."""

    group_centroid: np.ndarray  # (K / GROUP, 3)
    group_dipole: np.ndarray
    group_radius: np.ndarray
    centroid: np.ndarray  # (K, 3)
    dipole: np.ndarray
    radius: np.ndarray
    points: np.ndarray  # (K, L, 3)
    moments: np.ndarray  # (K, L, 3): a_i n_i, 0 on padding


def _nodes(pts: np.ndarray, mom: np.ndarray):
    """Centroid (weighted by |a_i n_i|), dipole and radius of each row of (rows, L, 3) members."""
    a = np.linalg.norm(mom, axis=2)
    # a row without weight (padding, or samples dropped by `_without`) centres on its members,
    # not on the origin: it adds nothing, and a small radius keeps it out of the near field
    a = np.where(a.sum(axis=1, keepdims=True) > 0, a, 1.0)
    centroid = np.sum(pts * a[..., None], axis=1) / a.sum(axis=1)[:, None]
    radius = np.sqrt(np.max(np.sum((pts - centroid[:, None]) ** 2, axis=2), axis=1))
    return centroid, mom.sum(axis=1), radius


def winding_tree(points: np.ndarray, normals: np.ndarray, areas: np.ndarray) -> WindingTree:
    """The tree of `points` for `winding_number` (host, numpy)."""
    return _indexed_tree(points, normals, areas)[0]


def _without(tree: WindingTree, slots: np.ndarray, drop: np.ndarray) -> WindingTree:
    """`tree` (from `_indexed_tree`, whose `slots` map each leaf entry to its sample, -1 on
    padding) with the samples where `drop` weighing nothing: the same shapes, so the same
    compiled sum. The nodes' centroids and radii are those of the samples left (with the
    whole tree's, the far-field sums are off by the dropped samples' shift of each centroid:
    a hemisphere's closing, re-closed so, sank by 1.4% of its radius)."""
    mom = np.where((slots >= 0) & ~drop[np.maximum(slots, 0)], 1.0, 0.0)[..., None] * tree.moments
    k = len(mom) // GROUP
    groups = _nodes(tree.points.reshape(k, -1, 3), mom.reshape(k, -1, 3))
    return WindingTree(*groups, *_nodes(tree.points, mom), tree.points, mom)


def _indexed_tree(points: np.ndarray, normals: np.ndarray, areas: np.ndarray):
    """`winding_tree`, and the sample behind each leaf entry ((K, L), -1 on padding)."""
    n = len(points)
    parts = 1 << max(int(np.ceil(np.log2(max(n / LEAF_SIZE, 1)))), 4)
    leaves = _kd_leaves(points, np.arange(n), parts)  # depth-first: GROUP in a row = a subtree
    real = len(leaves)
    leaves += [leaves[-1][:1]] * (-real % GROUP)  # a tiny input can have fewer leaves than parts
    size = max(len(lf) for lf in leaves)
    pts = np.zeros((len(leaves), size, 3))
    mom = np.zeros((len(leaves), size, 3))
    slots = np.full((len(leaves), size), -1)
    for i, lf in enumerate(leaves):
        pts[i, : len(lf)] = points[lf]
        pts[i, len(lf) :] = points[lf[0]]
        mom[i, : len(lf)] = areas[lf, None] * normals[lf]
        slots[i, : len(lf)] = lf
    mom[real:] = 0.0
    slots[real:] = -1
    k = len(leaves) // GROUP
    groups = _nodes(pts.reshape(k, -1, 3), mom.reshape(k, -1, 3))
    return WindingTree(*groups, *_nodes(pts, mom), pts, mom), slots


def _dipoles(d: jax.Array, m: jax.Array, use: jax.Array) -> jax.Array:
    """sum of m . d / (4 pi |d|^3) over the second axis where `use` (and d != 0)."""
    r2 = jnp.sum(d * d, axis=-1)
    ok = use & (r2 > 0)
    # r2 replaced where unused, not only the result: a query on a weightless entry (r2 = 0)
    # would otherwise give 0 * inf = nan in the gradient
    inv = jnp.where(ok, 1.0 / jnp.where(ok, r2, 1.0) ** 1.5, 0.0)
    return jnp.sum(jnp.sum(d * m, axis=-1) * inv, axis=1) / (4.0 * jnp.pi)


def _first(flags: jax.Array, k: int) -> tuple[jax.Array, jax.Array]:
    """Indices of up to k True entries of each row of `flags`, and whether each is True."""
    _, idx = jax.lax.top_k(flags.astype(jnp.float32), k)
    return idx, jnp.take_along_axis(flags, idx, axis=1)


def _block_sum(q, tree: WindingTree, group_k: int, leaf_k: int):
    """w at the queries `q` (B, 3) and the near-node counts (to check the static sizes)."""
    b = q.shape[0]
    dg = tree.group_centroid[None] - q[:, None]
    near_g = jnp.sum(dg * dg, -1) <= (BETA * tree.group_radius[None]) ** 2
    w = _dipoles(dg, tree.group_dipole[None], ~near_g)
    gi, g_ok = _first(near_g, group_k)
    li = (gi[..., None] * GROUP + jnp.arange(GROUP)).reshape(b, -1)  # leaves of the near groups
    valid = jnp.repeat(g_ok, GROUP, axis=1)
    dl = tree.centroid[li] - q[:, None]
    near_l = valid & (jnp.sum(dl * dl, -1) <= (BETA * tree.radius[li]) ** 2)
    w += _dipoles(dl, tree.dipole[li], valid & ~near_l)
    pick, l_ok = _first(near_l, leaf_k)
    leaf = jnp.take_along_axis(li, pick, axis=1)  # (B, leaf_k)
    dp = tree.points[leaf] - q[:, None, None]  # (B, leaf_k, L, 3)
    m = tree.moments[leaf] * l_ok[..., None, None]
    w += _dipoles(
        dp.reshape(b, -1, 3), m.reshape(b, -1, 3), jnp.ones(dp.shape[:-1], bool).reshape(b, -1)
    )
    return w, jnp.max(jnp.sum(near_g, 1)), jnp.max(jnp.sum(near_l, 1))


@partial(jax.jit, static_argnames=("group_k", "leaf_k"))
def _block(q, tree: WindingTree, group_k: int, leaf_k: int):
    """w at the queries `q` (B, 3), its gradient (B, 3) and the near-node counts: the gradient of
    the same sum (each query's w depends on that query alone, so the gradient of the total is
    every query's own; the node choices are constant under a small move of the query). One
    program for both uses: a value-only twin saves about 5% at 100k samples and costs a second
    compilation (1.2 s) on every cold run."""

    def total(x):
        w, ng, nl = _block_sum(x, tree, group_k, leaf_k)
        return jnp.sum(w), (w, ng, nl)

    g, (w, ng, nl) = jax.grad(total, has_aux=True)(q)
    return w, g, ng, nl


def winding_number(
    queries, points, normals, areas=None, tree: WindingTree | None = None, gradient: bool = False
):
    """The fast winding number w of the oriented samples (`points`, outward `normals`, per-sample
    `areas`, default `calibrated_areas(points, normals)`) at `queries` (m, 3): about 1 inside,
    0 outside.

    Host arrays in, a numpy (m,) array out (with `gradient`, also its gradient, (m, 3)); the
    sums run jit-compiled in float32 in blocks of `BLOCK` queries (see the module docstring for
    the approximation)."""
    q = np.asarray(queries, dtype=float)
    if q.ndim != 2 or q.shape[1] != 3:
        raise InputError(f"`queries` must be an (m, 3) array, got shape {q.shape}")
    if tree is None:
        p = np.asarray(points, dtype=float)
        nrm = np.asarray(normals, dtype=float)
        nrm = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
        areas = calibrated_areas(p, nrm) if areas is None else np.asarray(areas)
        tree = winding_tree(p, nrm, areas)
    # float32 in the samples' own frame (centred, unit size; w is unchanged by the move and the
    # scale): in raw coordinates a part 1e-3 across lying 1e4 from the origin sat within one
    # float32 step of itself and every query read outside
    centre, size = _frame(tree.points)
    dev = _to_frame(tree, centre, size)
    q = (q - centre) / size
    # blocks of nearby queries gather nearby nodes: 5-8% faster than in the callers' order
    # (100,000 queries by a bunny's samples: 3.3 s against 3.5-3.6 s); the same values
    order = _morton_order(q)
    q = q[order]
    n_groups = len(tree.group_centroid)
    group_k, leaf_k = min(16, n_groups), min(32, len(tree.centroid))
    out = np.empty(len(q))
    grad = np.empty((len(q), 3))
    for start in range(0, len(q), BLOCK):
        block = q[start : start + BLOCK]
        pad = jnp.asarray(
            np.concatenate([block, np.repeat(block[-1:], BLOCK - len(block), 0)]), jnp.float32
        )
        while True:
            w, g, ng, nl = _block(pad, dev, group_k, leaf_k)
            if int(ng) <= group_k and int(nl) <= leaf_k:
                break
            group_k = min(n_groups, 2 * group_k) if int(ng) > group_k else group_k
            leaf_k = min(GROUP * group_k, 2 * leaf_k) if int(nl) > leaf_k else leaf_k
        out[start : start + len(block)] = np.asarray(w, dtype=float)[: len(block)]
        grad[start : start + len(block)] = np.asarray(g, dtype=float)[: len(block)]
    out[order], grad[order] = out.copy(), grad / size
    return (out, grad) if gradient else out


def _frame(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and largest side of the box of `points` (any shape ending in 3); size 1 if flat."""
    flat = np.asarray(points, dtype=float).reshape(-1, 3)
    lo, hi = flat.min(axis=0), flat.max(axis=0)
    size = float(np.max(hi - lo))
    return (lo + hi) / 2, (size if size > 0 else 1.0)


def _to_frame(tree: WindingTree, centre: np.ndarray, size: float) -> WindingTree:
    """`tree` moved by -`centre` and scaled by 1/`size`, as float32 device arrays: positions and
    radii scale by 1/size, the dipoles and moments (area-weighted normals) by 1/size^2."""
    t = tree
    return WindingTree(
        *(
            jnp.asarray(a, dtype=jnp.float32)
            for a in (
                (t.group_centroid - centre) / size,
                t.group_dipole / size**2,
                t.group_radius / size,
                (t.centroid - centre) / size,
                t.dipole / size**2,
                t.radius / size,
                (t.points - centre) / size,
                t.moments / size**2,
            )
        )
    )


def _spread(x: np.ndarray) -> np.ndarray:
    """The 10 low bits of `x` spaced two bits apart (for a 3-D Morton code)."""
    x = x & 0x3FF
    x = (x | (x << 16)) & 0x30000FF
    x = (x | (x << 8)) & 0x300F00F
    x = (x | (x << 4)) & 0x30C30C3
    return (x | (x << 2)) & 0x9249249


def _morton_order(q: np.ndarray) -> np.ndarray:
    """An order of the points `q` (m, 3) along a Z-curve through a 32^3 grid of their box."""
    if len(q) < 2:
        return np.arange(len(q))
    lo, hi = q.min(axis=0), q.max(axis=0)
    cell = np.clip(((q - lo) / np.maximum(hi - lo, 1e-300) * 32).astype(np.int64), 0, 31)
    key = _spread(cell[:, 0]) | (_spread(cell[:, 1]) << 1) | (_spread(cell[:, 2]) << 2)
    return np.argsort(key, kind="stable")


class VolumeConstraints(NamedTuple):
    """Probe points away from the samples and their signed-distance values (see the module
    docstring). `undecided`: how many have a winding number within `RAMP` of 1/2 (over holes,
    past open boundaries). `closing` / `closing_normals`: samples of the winding number's
    closing surface where the data stop (`closing_samples`; empty unless asked for).
    `near_rims`, `shell`: how many of the points are `rim_probes` and `shell_probes`. `tree`:
    the samples' winding tree that valued them (for `contradicted`). `flipped`: the normals
    pointed into the solid and were flipped first (`points_inward`). `turned`: the samples whose
    normals pointed into the solid part by part, turned out after that (`inward_samples`). `level_median`: the median
    of the closing level's sites (`closing_level`; 1/2 on a closed surface)."""

    points: np.ndarray
    values: np.ndarray
    undecided: int
    near_rims: int = 0
    closing: np.ndarray = np.zeros((0, 3))
    closing_normals: np.ndarray = np.zeros((0, 3))
    buried: np.ndarray = np.zeros(0, dtype=bool)
    shell: int = 0
    tree: WindingTree | None = None
    flipped: bool = False
    turned: np.ndarray = np.zeros(0, dtype=bool)
    level_median: float = 0.5

    def summary(self) -> str:
        inside = int(np.sum(self.values < 0))
        return (
            f"inside/outside: {len(self.values):,} volume constraints from the winding number "
            f"({inside:,} inside, {len(self.values) - inside:,} outside; {self.shell:,} in the "
            f"shell {NEAR_SPACINGS:g} spacings off the samples, {self.near_rims:,} around "
            f"boundaries of the samples, {self.undecided:,} over holes or past open "
            f"boundaries); {len(self.closing):,} samples of the closing surface w = its level "
            f"(median {self.level_median:.2f})"
            + (
                f"; {int(self.buried.sum()):,} buried samples (inside on both sides) left out"
                if self.buried.any()
                else ""
            )
        )


_CHILDREN = np.array(np.meshgrid(*[[-0.25, 0.25]] * 3, indexing="ij")).reshape(3, -1).T


def _split(centres: np.ndarray, cell: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 8 children (centres, sizes) of the cells `centres` of sizes `cell`."""
    kids = centres[:, None, :] + cell[:, None, None] * _CHILDREN[None]
    return kids.reshape(-1, 3), np.repeat(cell / 2, 8)


def probe_points(points: np.ndarray, h: float, tree: cKDTree | None = None):
    """Octree probes in shells around `points` (see the module docstring), the finest cells of
    size `h`: `(probes, distance to the nearest sample, cell size)`."""
    tree = cKDTree(points) if tree is None else tree
    lo, hi = _probe_box(points)
    side = float(np.max(hi - lo))
    top = 0
    while h * 2**top < COARSEST_CELL * side:
        top += 1
    cell = h * 2**top
    dims = np.maximum(np.ceil((hi - lo) / cell).astype(int), 1)
    axes = [lo[k] + cell * (np.arange(dims[k]) + 0.5) for k in range(3)]
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    kept, kept_d, kept_c = [], [], []
    for level in range(top, -1, -1):
        cell = h * 2**level
        # below the top, only distances under the shell's and the refinement's bounds matter
        # (a far query is a k-d tree's slowest)
        bound = np.inf if level == top else SHELL[1] * cell + np.sqrt(3) * cell
        dist, _ = tree.query(centres, workers=-1, distance_upper_bound=bound)
        shell = np.all((centres >= lo) & (centres <= hi), axis=1) & (dist >= SHELL[0] * cell)
        if level < top:
            shell &= dist < SHELL[1] * cell
        kept.append(centres[shell])
        kept_d.append(dist[shell])
        kept_c.append(np.full(int(shell.sum()), cell))
        if level == 0:
            break
        # children (half the size) can hold probes of the finer shells
        refine = dist < SHELL[1] * cell / 2 + 0.5 * np.sqrt(3) * cell
        centres, _ = _split(centres[refine], np.full(int(refine.sum()), cell))
    return np.concatenate(kept), np.concatenate(kept_d), np.concatenate(kept_c)


def _probe_box(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = points.min(axis=0), points.max(axis=0)
    pad = PROBE_PADDING * float(np.max(hi - lo))
    return lo - pad, hi + pad


def volume_constraints(
    points,
    normals,
    spacing: float | None = None,
    areas=None,
    rims: bool = True,
    close: bool = False,
    bury: bool | None = None,
    orient: bool = False,
    rim: np.ndarray | None = None,
) -> VolumeConstraints:
    """Volume constraints for oriented 3-D samples (`points`, outward `normals`): octree probes
    away from the samples, the cells where w is near 1/2 refined down to the finest probe size,
    and probes around the boundary samples, each valued by `signed_values` (see the module
    docstring). `spacing`: the samples' median nearest-neighbour distance (computed
    when None). `rims`: add `rim_probes` around the boundary samples (leave them out for a
    noisy cloud, which a fit approximates: there the boundary test also fires on gaps in the
    noise, and probes a few spacings from a noisy surface pull the smoothed fit off it;
    measured on a virtual range scan of the bunny, the precision at 0.5% of the surface above
    its base fell from 99.6% to 93.8% with them). `shell_probes` come with every call.
    `rim`: the samples' `boundary_mask`, when already known (`open_shells` returns it).
    `close`: also sample the closing surface (`closing_samples`), seeded by the probes over
    holes and past open boundaries. `bury`: also find the buried samples (`buried_samples`;
    default: with `close`). `orient`: when the normals all point into the solid
    (`points_inward`), flip them first (the result's `flipped` says so), then turn out the samples
    of parts whose normals point into the solid (`inward_samples`; the result's `turned`)."""
    p = np.asarray(points, dtype=float)
    nrm = np.asarray(normals, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or nrm.shape != p.shape:
        raise InputError(
            f"volume constraints need (n, 3) points and normals, got {p.shape} and {nrm.shape}"
        )
    nrm = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
    tree = cKDTree(p)
    if spacing is None:
        spacing = point_spacing(p)
    finest = PROBE_CELL_SPACINGS * spacing
    probes, dist, cell = probe_points(p, finest, tree)
    if len(probes) > MAX_PROBES:  # the finest shell holds most: its count goes as 1 / h^2
        finest *= np.sqrt(len(probes) / MAX_PROBES)
        probes, dist, cell = probe_points(p, finest, tree)
    if rim is None:
        rim = boundary_mask(p, nrm, tree=tree)
    if areas is None:
        areas = calibrated_areas(p, nrm, tree=tree, spacing=spacing, rim=rim)
    wtree = winding_tree(p, nrm, np.asarray(areas))
    flipped, turned = False, np.zeros(len(p), dtype=bool)
    if orient:
        flipped, turned, nrm, wtree, areas, again = oriented(
            p, nrm, spacing, np.asarray(areas), wtree, tree
        )
        rim = rim if again is None else again
    bury = close if bury is None else bury
    buried = buried_samples(p, nrm, spacing, wtree, tree) if bury else np.zeros(len(p), dtype=bool)
    level = closing_level(p, nrm, spacing, wtree, tree, use=~buried)
    # w with its gradient (they come together): each probe is evaluated once
    w, g = winding_number(probes, None, None, tree=wtree, gradient=True)
    finest *= 1.01
    lo, hi = _probe_box(p)
    # the level at each probe, evaluated once with its w (a median over LEVEL_NEIGHBOURS sites)
    lev = level(probes)
    done = [(probes, w, g, lev)]
    while True:
        # Where w passes its level far from the data (a hole's cap), the probes' sign changes
        # there: refine those cells so that the fit's zero crossing follows that level closely.
        cap = (np.abs(w - lev) < RAMP) & (cell > finest)
        if not cap.any():
            break
        done[-1] = tuple(a[~cap] for a in done[-1])
        probes, cell = _split(probes[cap], cell[cap])
        dist, _ = tree.query(probes, workers=-1)
        ok = np.all((probes >= lo) & (probes <= hi), axis=1) & (dist >= SHELL[0] * cell)
        probes, cell, dist = probes[ok], cell[ok], dist[ok]
        w, g = winding_number(probes, None, None, tree=wtree, gradient=True)
        lev = level(probes)
        done.append((probes, w, g, lev))
    probes, w, grad, lev = (np.concatenate([a[k] for a in done]) for k in range(4))
    # a refined cap cell's children can be probes of the distance shells too: keep one of each
    key = np.round((probes - lo) / (0.25 * finest)).astype(np.int64)
    _, first = np.unique(key, axis=0, return_index=True)
    first = np.sort(first)
    probes, w, grad, lev = probes[first], w[first], grad[first], lev[first]
    reach = min(SHELL[0] * finest, RIM_REACH * spacing)
    near = rim_probes(p[rim] if rims else p[:0], spacing, reach, tree)
    shell, shell_out = shell_probes(p[~buried], nrm[~buried], spacing, tree)
    # side: 0 for a rim probe, +1 / -1 for a shell probe along / against its sample's normal
    side = np.concatenate([np.zeros(len(near), dtype=int), np.where(shell_out, 1, -1)])
    near = np.concatenate([near, shell])
    inside_box = np.all((near >= lo) & (near <= hi), axis=1)
    near, side = near[inside_box], side[inside_box]
    w_near, g_near = winding_number(near, None, None, tree=wtree, gradient=True)
    # A shell probe is kept where w agrees with the side of its sample it stands on (outside
    # along the normal, inside against it). Where the two disagree (beside a hole, where w
    # passes 1/2 away from the fitted cap) it has no sign to give: kept, such probes made small
    # bubbles under the unseen base of a scanned bunny; dropping every probe with w within
    # `RAMP` of 1/2 instead lost those that hold an open real scan (anchor: far share 1.78% ->
    # 2.83%).
    lev_near = level(near)
    keep = (side == 0) | ((w_near < lev_near) == (side > 0))
    near, side, w_near, g_near = near[keep], side[keep], w_near[keep], g_near[keep]
    lev_near = lev_near[keep]
    n_rim, n_shell = int(np.sum(side == 0)), int(np.sum(side != 0))
    probes = np.concatenate([probes, near])
    w, grad = np.concatenate([w, w_near]), np.concatenate([grad, g_near])
    lev = np.concatenate([lev, lev_near])
    # distances to the samples the fit keeps (a buried sample is no surface to measure from)
    kept = cKDTree(p[~buried]) if buried.any() else tree
    dist, _ = kept.query(probes, workers=-1)
    values = signed_values(w, grad, dist, lev)
    undecided = np.abs(w - lev) < RAMP
    closing = (np.zeros((0, 3)), np.zeros((0, 3)))
    if close:
        closing = closing_samples(p, probes[undecided], spacing, wtree, tree, level)
        closing = _out_of_walls(*closing, p, nrm, spacing, tree)
        # each hole closed again with the others closed (`reclosed`), and the probes valued
        # by the samples and those closings together: where several holes open one solid, w
        # alone reads well under 1 inside it and each closing bows in
        # (exact fits only: on the noisy open leg scan it grew its far share 19% -> 33%)
        held = np.zeros(len(closing[0]), dtype=bool)
        if bury:
            *closing, held = reclosed(p, nrm, np.asarray(areas), closing, spacing)
        if held.any():
            # w is a sum over dipoles: the closings' share alone is added to the samples' w
            # the probes already have (a tree of the closing samples is a fraction of one of
            # the samples and closings together)
            c, cn = closing[0][held], closing[1][held]
            extra = winding_tree(c, cn, closing_areas(cn, spacing))
            w_c, g_c = winding_number(probes, None, None, tree=extra, gradient=True)
            w, grad = w + w_c, grad + g_c
            values = signed_values(w, grad, dist, lev)
    return VolumeConstraints(
        probes,
        values,
        int(np.sum(undecided)),
        n_rim,
        *closing,
        buried,
        shell=n_shell,
        tree=wtree,
        flipped=flipped,
        turned=turned,
        level_median=float(np.median(level.levels)) if len(level.levels) else 0.5,
    )


def _neighbours(tree: cKDTree, q: np.ndarray, k: int, reach: float):
    """`(ok, idx)`, (m, k) arrays: the `k` nearest samples of `tree` to each of `q` (itself
    included when it is one) and which of them lie within `reach` (`idx` 0 where not)."""
    k = min(k, tree.n)
    d, idx = tree.query(q, k=k, distance_upper_bound=reach, workers=-1)
    ok = np.isfinite(d.reshape(len(q), k))
    return ok, np.where(ok, idx.reshape(len(q), k), 0)


def pieces(points: np.ndarray, spacing: float, tree: cKDTree | None = None) -> np.ndarray:
    """A label per sample: the pieces of `points` linked by each sample's `SHELL_LINK_K` nearest
    samples within `SHELL_LINK` spacings (a k-nearest graph: its size grows with the samples,
    where all pairs within that distance would grow with their density too)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(points)
    tree = cKDTree(points) if tree is None else tree
    ok, idx = _neighbours(tree, points, SHELL_LINK_K + 1, SHELL_LINK * spacing)
    rows = np.repeat(np.arange(n), ok.shape[1]).reshape(ok.shape)[ok]
    graph = coo_matrix((np.ones(len(rows), np.int8), (rows, idx[ok])), shape=(n, n))
    return connected_components(graph, directed=False)[1]


class Shells(NamedTuple):
    """`shell_samples`' answer: `mask`, which samples lie on open shells; `pieces` and
    `shells`, how many pieces were tested and found open; `level`, the shells' median
    mid-value of w (NaN without any); `two_faced`, how many of the shells are two-faced
    (`two_faced`); `flaps`, how many are open sheets hanging on closed pieces (`flap_samples`);
    `flipped`, `turned`: how `open_shells(orient=True)` turned the normals out (`oriented`);
    `reoriented`: the samples whose normals it turned first, on pieces whose normals faced both
    ways at one place, so that they agree along the surface (`jaxrbf._normals.orient_normals`)."""

    mask: np.ndarray
    pieces: int
    shells: int
    level: float
    two_faced: int = 0
    flaps: int = 0
    flipped: bool = False
    turned: np.ndarray | None = None
    reoriented: np.ndarray | None = None

    def summary(self) -> str:
        two = (
            f", {self.two_faced} of them two-faced (a sheet sampled on both faces, wound both "
            "ways, as an artist models a cloth or a leaf)"
            if self.two_faced
            else ""
        )
        if self.flaps:
            two += (
                f", {self.flaps} of them hanging on closed pieces (a cape on a figure: read as a "
                "sheet sample by sample)"
            )
        read = (
            f"median mid-value of w across them {self.level:.2f}, a closed surface's 1/2{two}"
            if np.isfinite(self.level)
            else two[2:]
        )
        return (
            f"{int(self.mask.sum()):,} samples on {self.shells} open "
            f"{'piece' if self.shells == 1 else 'pieces'} that bound no volume ({read}): meshed "
            "as thin two-sided slabs round them, not closed"
        )


def _sheets_of(p, flags, spacing: float, tree) -> np.ndarray:
    """The samples `flags` (two-faced, `facing_pairs`; or flaps, `flap_samples`) in linked
    groups (`pieces`) of `TWO_FACED_PART` of the samples and `SHELL_MIN_SAMPLES` or more (a few
    apart are a thin part's edge, a fold, a contact), with the samples most of whose
    `SHELL_LINK_K` nearest are in such a group, `TWO_FACED_GROW` times (a sheet's border, whose
    samples have fewer neighbours to face, or read less of a jump)."""
    found = np.flatnonzero(flags)
    sheet = np.zeros(len(p), dtype=bool)
    least = max(SHELL_MIN_SAMPLES, TWO_FACED_PART * len(p))
    if len(found) < least:
        return sheet
    label = pieces(p[found], spacing)
    sheet[found] = np.bincount(label)[label] >= least
    if sheet.any():
        tree = cKDTree(p) if tree is None else tree
        ok, idx = _neighbours(tree, p, SHELL_LINK_K + 1, SHELL_LINK * spacing)
        for _ in range(TWO_FACED_GROW):
            sheet |= np.where(ok, sheet[idx], False).sum(axis=1) > ok.sum(axis=1) / 2
    return sheet


def flap_samples(points, normals, spacing: float, wtree: WindingTree, tree=None) -> np.ndarray:
    """Which samples read as an open sheet on their own: w `JUMP_SPACINGS` spacings along and
    against the normal jumps by more than `SHELL_JUMP` with a mid-value below `FLAP_LEVEL` in
    magnitude (a sheet's +1/2 and -1/2), read at the samples `points_inward` reads
    (`_read_at`) and carried to the rest from the nearest read. A piece that
    reads closed as a whole can hold one: a cape, a skirt or a wing hanging on a figure, which
    closing would span with a balloon from its edge round to the body."""
    p = np.asarray(points, dtype=float)
    idx = _read_at(len(p))
    nrm = np.asarray(normals, dtype=float)
    mid, jump = _across(p, nrm, idx, spacing, wtree)
    flap = (np.abs(mid) < FLAP_LEVEL) & (jump > SHELL_JUMP)
    # a thin closed wall's readings against the normal land by its other face, and read as a
    # sheet's: a sample with a face turned the other way behind it is no flap (`_backed`)
    tree = cKDTree(p) if tree is None else tree
    some = np.flatnonzero(flap)
    flap[some[_backed(p, nrm, idx[some], spacing, tree)]] = False
    if len(idx) == len(p):
        return flap
    return flap[cKDTree(p[idx]).query(p, workers=-1)[1]]


def _across(p, nrm, idx, spacing: float, wtree: WindingTree):
    """`(mid, jump)` at the samples `idx`: w's mean and difference, read `JUMP_SPACINGS` spacings
    against the normal (in) and along it (out): a closed surface's 1/2 and 1, a sheet's 0 and 1."""
    step = JUMP_SPACINGS * spacing * nrm[idx]
    w = winding_number(np.concatenate([p[idx] + step, p[idx] - step]), None, None, tree=wtree)
    w_out, w_in = w[: len(idx)], w[len(idx) :]
    return (w_in + w_out) / 2, w_in - w_out


def _backed(
    p, nrm, idx, spacing: float, tree: cKDTree, steps: int = BACKED_SPACINGS, sign: float = -1.0
) -> np.ndarray:
    """Which samples `idx` have another face behind them (`BACKED_SPACINGS`): going against
    the normal (`sign` = +1: along it, a face in front) up to `steps` spacings, a sample
    within `BACKED_WAY` spacings of the way (one of its `BACKED_NEIGHBOURS` nearest) faces the
    other way."""
    return np.isfinite(_face_ahead(p, nrm, idx, spacing, tree, steps, sign))


def _face_ahead(
    p, nrm, idx, spacing: float, tree: cKDTree, steps: int, sign: float, near: float = 0.5
) -> np.ndarray:
    """For samples `idx`, the distance along `sign` times the normal to the nearest sample
    that faces the other way (cosine below -1/2), lies within `BACKED_WAY` spacings of the way
    (one of the `BACKED_NEIGHBOURS` nearest to a point of it, taken a spacing apart up to
    `steps` spacings) and more than `near` spacings ahead; inf where there is none."""
    ahead_by = np.full(len(idx), np.inf)
    m = min(BACKED_NEIGHBOURS, len(p))
    for k in range(1, int(steps) + 1):
        dist, j = tree.query(p[idx] + sign * k * spacing * nrm[idx], k=m, workers=-1)
        dist, j = dist.reshape(len(idx), m), j.reshape(len(idx), m)
        t = sign * np.einsum("ikj,ij->ik", p[j] - p[idx, None], nrm[idx])
        facing = np.einsum("ikj,ij->ik", nrm[j], nrm[idx]) < -0.5
        hit = (dist <= BACKED_WAY * spacing) & (t > near * spacing) & facing
        ahead_by = np.minimum(ahead_by, np.min(np.where(hit, t, np.inf), axis=1))
    return ahead_by


def two_faced(points, normals, spacing: float, tree: cKDTree | None = None) -> np.ndarray:
    """Which samples lie on a two-faced sheet: `facing_pairs` of `TWO_FACED_PAIRS` or more."""
    return facing_pairs(points, normals, spacing, tree) >= TWO_FACED_PAIRS


def facing_pairs(points, normals, spacing: float, tree: cKDTree | None = None) -> np.ndarray:
    """How many of each sample's `TWO_FACED_K` nearest (within `TWO_FACED_LINK` spacings) face
    the other way and lie in its tangent plane (less than `TWO_FACED_OFFSET` spacings off it).
    An artist models a cloth, a leaf or a card as
    two coincident copies of one sheet wound opposite ways; their samples' dipoles cancel, so w
    reads no jump across it (as across a thin closed plate, whose two faces' samples lie a
    thickness apart along their normals), and a fit of samples that face both ways at one place
    has no surface to give (a made sphere with such a cloth beside it: 28% of the samples more
    than 4 spacings from the output, refused). The sheet is open: its slab is its surface."""
    p = np.asarray(points, dtype=float)
    nrm = np.asarray(normals, dtype=float)
    tree = cKDTree(p) if tree is None else tree
    ok, safe = _neighbours(tree, p, TWO_FACED_K + 1, TWO_FACED_LINK * spacing)
    against = np.einsum("ij,ikj->ik", nrm, nrm[safe]) < -0.5
    off = np.abs(np.einsum("ij,ikj->ik", nrm, p[safe] - p[:, None, :]))
    return np.sum(ok & against & (off < TWO_FACED_OFFSET * spacing), axis=1)


#: `facing_beside`: a neighbour lies beside a sample when its offset makes less than this sine
#: with the sample's tangent plane (17 degrees): on its surface, not across a thin part's gap
#: (the other face of a plate t thick only from 3.2 t away, beyond the link for t > 1 spacing).
BESIDE = 0.3


def facing_beside(points, normals, spacing: float, tree: cKDTree | None = None) -> np.ndarray:
    """How many of each sample's `TWO_FACED_K` nearest (within `TWO_FACED_LINK` spacings) face
    the other way (cosine below -1/2) and lie beside it (`BESIDE`). `facing_pairs` asks for the
    neighbours in the tangent plane itself (a coincident face); this one also counts those on a
    curved surface around it, where normals that point either way at random disagree (80% of
    the samples of a bunny whose normals were flipped at random have two or more; at most 3.5%
    of any of the benchmark's inputs, 27% of the made cloth figure's)."""
    p = np.asarray(points, dtype=float)
    nrm = np.asarray(normals, dtype=float)
    tree = cKDTree(p) if tree is None else tree
    ok, safe = _neighbours(tree, p, TWO_FACED_K + 1, TWO_FACED_LINK * spacing)
    e = p[safe] - p[:, None, :]
    against = np.einsum("ij,ikj->ik", nrm, nrm[safe]) < -0.5
    beside = np.abs(np.einsum("ij,ikj->ik", nrm, e)) < BESIDE * np.linalg.norm(e, axis=2)
    return np.sum(ok & against & beside, axis=1)


def shell_samples(
    points,
    normals,
    spacing: float,
    wtree: WindingTree,
    tree: cKDTree | None = None,
    seed=0,
    level: float = SHELL_LEVEL,
    rim: np.ndarray | None = None,
    areas: np.ndarray | None = None,
    faced: np.ndarray | None = None,
    flaps: bool = False,
    label: np.ndarray | None = None,
) -> Shells:
    """Which samples lie on open shells: pieces (`pieces`) that bound no volume, such as a
    sheet, a leaf, a shallow cap or an artist's car body without its underside. Across a
    closed surface w reads about 1 just inside and 0 just outside (mid-value 1/2); across an
    open sheet +1/2 and -1/2 (mid-value 0). A piece whose median mid-value, `JUMP_SPACINGS`
    spacings along and against the normals (where the sum over discrete samples is smooth), is
    below `level` (`SHELL_LEVEL`) in magnitude (normals turned into the solid turn its sign) is
    no more than half of a closed surface; given the samples' `rim` (`boundary_mask`) and
    `areas`, so is one below `SHELL_OPENING_LEVEL` whose openings span `SHELL_OPENING` of its
    area or more (`openings`); given `faced` (`facing_pairs`), so is a piece more than
    `TWO_FACED_SHARE` of whose samples are on two-faced sheets, and such a sheet by itself;
    with `flaps`, so are the open sheets that hang on pieces that read closed (`flap_samples`).
    Closing such a piece (a lid over a bowl or a vase, a lumpy cap across a sheet that w never
    puts inside) invents a large surface that the input does not have: it is better kept as it
    is, thickened (`jaxrbf._cavities.shell_slabs`).

    Pieces of fewer than `SHELL_SMALL` samples, and those of fewer than `SHELL_MIN_SAMPLES` whose
    jump is unclear, go with the nearest piece judged (`label`: the samples' `pieces`, when
    already known). Cost: 2 x `SHELL_TESTED` evaluations of
    w per piece of `SHELL_SMALL` samples or more."""
    p = np.asarray(points, dtype=float)
    nrm = np.asarray(normals, dtype=float)
    mask = np.zeros(len(p), dtype=bool)
    if len(p) < SHELL_MIN_SAMPLES:
        return Shells(mask, 0, 0, float("nan"))
    tree = cKDTree(p) if tree is None else tree
    label = pieces(p, spacing, tree) if label is None else label
    count = np.bincount(label)
    big = np.flatnonzero(count >= SHELL_SMALL)
    # Sheets within pieces first: two-faced ones (`faced`) and flaps hanging on closed parts
    # are open by themselves, and the rest of their piece is judged without them (their rims
    # are not its openings, their readings not its mid-value).
    share = np.zeros(len(count))
    part = flap = np.zeros(len(p), dtype=bool)
    if faced is not None:
        raw = np.asarray(faced) >= TWO_FACED_PAIRS
        share = np.bincount(label, weights=raw.astype(float), minlength=len(count)) / count
        part = _sheets_of(p, raw, spacing, tree) & (share[label] <= TWO_FACED_SHARE)
    if flaps:
        flap = _sheets_of(p, flap_samples(p, nrm, spacing, wtree, tree), spacing, tree)
        flap &= ~part & (share[label] <= TWO_FACED_SHARE)
        # most of its piece: a sheet on its own, which the piece's own reading judges
        most = np.bincount(label, weights=flap.astype(float), minlength=len(count)) / count
        flap &= most[label] <= TWO_FACED_SHARE
    hanging = part | flap
    if hanging.any() and not hanging.all():
        # what the sheets leave beside them in bits of fewer than SHELL_SMALL samples (a
        # sample or two at a sheet's free edge, which its reading misses) goes with them: left
        # alone, a stray sample off the rest's surface grows a closing of its own (1,186
        # closing samples round one on a made cloth's edge)
        rest = np.flatnonzero(~hanging)
        bits = pieces(p[rest], spacing)
        small = rest[np.bincount(bits)[bits] < SHELL_SMALL]
        by = cKDTree(p[hanging]).query(p[small], distance_upper_bound=SHELL_LINK * spacing)[0]
        hanging[small[np.isfinite(by)]] = True  # beside the sheets, not a gap elsewhere
    # each piece's samples off the sheets, in order
    free = np.flatnonzero(~hanging)
    free = free[np.argsort(label[free], kind="stable")]
    members = np.split(free, np.cumsum(np.bincount(label[free], minlength=len(count)))[:-1])
    big = np.array([g for g in big if len(members[g])], dtype=np.int64)
    rng = np.random.default_rng(seed)
    picks = [rng.choice(members[g], min(len(members[g]), SHELL_TESTED), replace=False) for g in big]
    levels, doubled, whole = [], len(np.unique(label[part])), 0
    undecided = count < SHELL_SMALL
    if picks:
        idx = np.concatenate(picks)
        mid, jump = _across(p, nrm, idx, spacing, wtree)
        ends = np.cumsum([len(k) for k in picks])
        wide = None
        if rim is not None and areas is not None:
            wide = openings(p, label, rim & ~hanging, areas, spacing) >= SHELL_OPENING
        for g, sel in zip(big, np.split(np.arange(len(idx)), ends[:-1]), strict=True):
            if share[g] > TWO_FACED_SHARE:  # no jump to read across it: open as it is
                mask[label == g] = True
                levels.append(mid[sel])
                doubled += 1
                whole += 1
                continue
            # normals turned into the solid turn w and the side read: the jump stays, the
            # mid-value changes sign (a closed piece reads -1/2)
            m = abs(np.median(mid[sel]))
            open_ = m < level or (wide is not None and wide[g] and m < SHELL_OPENING_LEVEL)
            if open_ and np.mean(_backed(p, nrm, idx[sel], spacing, tree)) >= BACKED_SHARE:
                open_ = False  # a thin closed part
            # a piece a few spacings across subtends little from JUMP_SPACINGS off: its jump
            # reads about 1/2 where a large sheet's reads 1 (a thin closed plate's still 0)
            few = count[g] < SHELL_MIN_SAMPLES
            if np.median(jump[sel]) > (SHELL_JUMP / 2 if few else SHELL_JUMP):
                if open_:
                    mask[label == g] = True
                    levels.append(mid[sel])
            elif few:  # unclear: as if unread
                undecided[g] = True
    flapped = len(np.unique(label[flap & ~mask]))
    mask |= hanging
    small = undecided[label]
    if levels and small.any():
        # a few samples off on their own (random sampling leaves gaps) go with the nearest
        # piece that was read
        read = np.flatnonzero(~small)
        _, near = cKDTree(p[read]).query(p[small], workers=-1)
        mask[small] = mask[read[near]]
    found = float(np.median(np.concatenate(levels))) if levels else float("nan")
    return Shells(
        mask, len(big), len(levels) + (doubled - whole) + flapped, found, doubled, flapped
    )


def openings(points, label, rim, areas, spacing: float) -> np.ndarray:
    """Per piece (`label`), the share of its area (the sum of the samples' `areas`) that its
    openings span: each rim (`rim_groups` of the `rim` samples, `RIM_MIN` or more) counts with
    the area of its convex hull in its own plane, for the piece that holds most of its
    samples."""
    from scipy.spatial import ConvexHull, QhullError

    spanned = np.zeros(int(label.max()) + 1)
    for loop in rim_groups(points, rim, spacing, smallest=RIM_MIN):
        q = points[loop] - points[loop].mean(axis=0)
        plane = np.linalg.svd(q, full_matrices=False)[2][:2]
        try:
            hull = ConvexHull(q @ plane.T).volume  # a 2-D hull's volume is its area
        except QhullError:  # a rim on a line spans nothing
            continue
        spanned[np.bincount(label[loop]).argmax()] += hull
    return spanned / np.maximum(np.bincount(label, weights=areas), 1e-300)


def open_shells(
    points, normals, spacing: float, seed: int = 0, noisy: bool = False, orient: bool = False
):
    """`shell_samples` of the samples, with the winding tree built for it, the samples'
    `calibrated_areas` and their `boundary_mask`, as `volume_constraints` computes them (pass
    them on): `(shells, areas, rim)`. `noisy` (a cloud the fit approximates, a scan): at
    `SHELL_LEVEL_NOISY`, without the rims' `openings` (there the boundary test also fires on
    gaps, and an opening is most often a part of a closed object that no view saw; nor two-faced
    sheets, `two_faced`). `orient`: turn the normals out first (`oriented`; the result's
    `flipped` and `turned` say how, and its mask is of the samples so oriented)."""
    p = np.asarray(points, dtype=float)
    nrm = np.asarray(normals, dtype=float)
    nrm = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
    tree = cKDTree(p)
    faced = None if noisy else facing_pairs(p, nrm, spacing, tree)
    swapped = np.zeros(len(p), dtype=bool)
    label = None
    if orient:
        # pieces whose samples face both ways at one place, in patches or mostly: their normals
        # point either way (a soup wound at random, an unoriented estimate) or the piece is
        # sampled on two coincident faces. Either way the axes are kept and the signs made to
        # agree along the surface, as for a bare cloud: a soup's solid comes out a solid, a
        # two-faced sheet a one-faced sheet (open: a shell below, as before). Noisy clouds too
        # (a scan whose normals came unoriented): beside a sample means within 17 degrees of its
        # tangent plane, and a noisy scan's oriented normals rarely disagree there (0.002)
        label = pieces(p, spacing, tree)
        raw = facing_beside(p, nrm, spacing, tree) >= TWO_FACED_PAIRS
        share = np.bincount(label, weights=raw.astype(float)) / np.bincount(label)
        mixed = np.flatnonzero((share > MIXED_SHARE)[label])
        if len(mixed) >= SHELL_SMALL:
            from ._normals import orient_normals

            again = orient_normals(p[mixed], nrm[mixed])
            swapped[mixed] = np.einsum("ij,ij->i", again, nrm[mixed]) < 0
            nrm = np.where(swapped[:, None], -nrm, nrm)
            if faced is not None:
                faced = facing_pairs(p, nrm, spacing, tree)
    rim = boundary_mask(p, nrm, tree=tree)
    areas = calibrated_areas(p, nrm, tree=tree, spacing=spacing, rim=rim)
    wtree = winding_tree(p, nrm, areas)
    flipped, turned = False, np.zeros(len(p), dtype=bool)
    if orient:
        # first: a part wound the other way reads as a sheet where it crosses another part
        flipped, turned, nrm, wtree, areas, again = oriented(p, nrm, spacing, areas, wtree, tree)
        if again is not None:  # single samples turned: they faced others the other way
            rim = again
            if faced is not None:
                faced = facing_pairs(p, nrm, spacing, tree)
    found = shell_samples(
        p,
        nrm,
        spacing,
        wtree,
        tree,
        seed=seed,
        level=SHELL_LEVEL_NOISY if noisy else SHELL_LEVEL,
        rim=None if noisy else rim,
        areas=areas,
        # a noisy cloud's thin parts read two-faced as well (their faces a noise width apart)
        faced=faced,
        flaps=not noisy,
        label=label,
    )
    # the open shells keep their normals as given (their slabs do not ask which way they face,
    # and on an open sheet a concave stretch reads below 0 however it is wound); `turned`
    # after `reoriented`, which says where the signs were made to agree (both turn signs)
    keep = ~found.mask
    return (
        found._replace(flipped=flipped, turned=turned & keep, reoriented=swapped & keep),
        areas,
        rim,
    )


def oriented(points, normals, spacing: float, areas, wtree: WindingTree, tree=None):
    """`(flipped, turned, normals, wtree, areas, rim)`: the normals turned out where they point
    into the solid, all of them (`points_inward`: `flipped`), then part by part
    (`inward_samples`) and sample by sample (`contrary_samples`); `turned` masks both, and the
    winding tree is that of the samples so oriented. `areas`: the samples' (a part's sign does
    not change them); after single samples were turned, which changes the boundary test
    (`boundary_mask`) and with it the areas, both are read again and `rim` is the new boundary
    mask (None when no single sample was turned)."""
    p = np.asarray(points, dtype=float)
    nrm = np.asarray(normals, dtype=float)
    idx, w = sample_readings(p, wtree)  # `points_inward`'s, shared with `inward_samples`
    flipped = bool(np.median(w) < -ORIENT_LEVEL)
    if flipped:
        nrm = -nrm
        wtree = winding_tree(p, nrm, areas)
        w = -w  # w is linear in the normals
    turned = inward_samples(p, nrm, spacing, wtree, tree, readings=(idx, w))
    if turned.any():  # parts wound the other way, turned out one by one
        nrm = np.where(turned[:, None], -nrm, nrm)
        wtree = winding_tree(p, nrm, areas)
    lone = contrary_samples(p, nrm, spacing, areas, wtree, tree)
    rim = None
    if lone.any():  # single samples against their surface, turned one by one
        nrm = np.where(lone[:, None], -nrm, nrm)
        tree = cKDTree(p) if tree is None else tree
        rim = boundary_mask(p, nrm, tree=tree)
        areas = calibrated_areas(p, nrm, tree=tree, spacing=spacing, rim=rim)
        wtree = winding_tree(p, nrm, np.asarray(areas))
    return flipped, turned ^ lone, nrm, wtree, areas, rim


#: `contrary_samples`: rounds, and the jump across a sample below which it is turned.
CONTRARY_ROUNDS, CONTRARY_JUMP = 2, -0.5


def contrary_samples(
    points, normals, spacing: float, areas, wtree: WindingTree, tree=None
) -> np.ndarray:
    """Which samples face against their surface one by one (a normal flipped here and there: a
    scanner's at a grazing view, an estimate's): w jumps by about +1 across a sample from
    `JUMP_SPACINGS` spacings along its normal to as far against it (`_across`), the other way
    at a flipped one, since its own dipole is a small part of w there. Read only at samples
    with a neighbour facing the other way (cosine below -1/2, among `TWO_FACED_K` within
    `TWO_FACED_LINK` spacings) whose two readings are clear of other samples by `NEAR_CLEAR` of
    their distance (not across a thin part, where w is rough); turned below `CONTRARY_JUMP`, in
    `CONTRARY_ROUNDS` rounds (each on w with the last round's turns). 10k samples of the bunny
    with 5% / 20% of their normals flipped at random: 478 of 525 / 1,815 of 2,033 turned, none
    wrongly; 0-12 samples of the benchmark's inputs (126 of the beetle's 100k, all on its open
    shells, which keep their normals as given). `areas`: the samples', for the tree rebuilt
    between rounds."""
    p = np.asarray(points, dtype=float)
    nrm = np.asarray(normals, dtype=float).copy()
    tree = cKDTree(p) if tree is None else tree
    turned = np.zeros(len(p), dtype=bool)
    ok, safe = _neighbours(tree, p, TWO_FACED_K + 1, TWO_FACED_LINK * spacing)
    cand = np.flatnonzero(np.any(ok & (np.einsum("ij,ikj->ik", nrm, nrm[safe]) < -0.5), axis=1))
    if len(cand) == 0:
        return turned
    t = JUMP_SPACINGS * spacing
    d_out, _ = tree.query(p[cand] + t * nrm[cand], workers=-1)
    d_in, _ = tree.query(p[cand] - t * nrm[cand], workers=-1)
    cand = cand[(d_out >= NEAR_CLEAR * t) & (d_in >= NEAR_CLEAR * t)]
    for r in range(CONTRARY_ROUNDS):
        if len(cand) == 0:
            break
        if r:  # w with the last round's turns
            wtree = winding_tree(p, nrm, areas)
        _, jump = _across(p, nrm, cand, spacing, wtree)
        flip = cand[jump < CONTRARY_JUMP]
        if len(flip) == 0:
            break
        nrm[flip] = -nrm[flip]
        turned[flip] = ~turned[flip]
    return turned


def points_inward(points, wtree: WindingTree, tested: int = ORIENT_TESTED) -> bool:
    """Whether the normals of the samples `points` (those of `wtree`) point into the solid
    instead of out of it: the median winding number at (up to `tested` of) the samples reads
    below -`ORIENT_LEVEL`. At a sample its own sheet gives 1/2, and the rest of a closed surface
    whose normals point out adds about 0 (median 0.47 on the closed test meshes), of an open
    one less (0.32 on a hemisphere, 0.23 on the beetle's open car body); every sign flips with
    the normals. A flat open sheet reads 0 either way: it has no inside, and is left as it is.
    Given normals are trusted otherwise, one by one; this catches the consistent flip of a whole
    cloud (a tool that orients towards the inside; the global sign of Open3D's
    `orient_normals_consistent_tangent_plane` is arbitrary)."""
    p = np.asarray(points, dtype=float)
    return bool(np.median(sample_readings(p, wtree, tested)[1]) < -ORIENT_LEVEL)


def sample_readings(points, wtree: WindingTree, tested: int = ORIENT_TESTED):
    """`(idx, w)`: the winding number at (up to `tested` of, a seeded random subset) the samples
    `points`, those of `wtree` (`points_inward`, `inward_samples`)."""
    p = np.asarray(points, dtype=float)
    idx = _read_at(len(p), tested)
    return idx, np.asarray(winding_number(p[idx], None, None, tree=wtree))


def _read_at(n: int, tested: int = ORIENT_TESTED) -> np.ndarray:
    """The samples `sample_readings` reads: all `n`, or a seeded random `tested` of them."""
    if n <= tested:
        return np.arange(n)
    return np.sort(np.random.default_rng(0).choice(n, tested, replace=False))


#: `inward_samples`: w is read at the samples `points_inward` reads (`sample_readings`: up to
#: ORIENT_TESTED, a random subset beyond), and each sample takes the median of its INWARD_K
#: nearest of those within INWARD_LINK spacings (of that subset: scaled by the square root of
#: the share read) whose normals agree with its own (cosine above INWARD_COS).
INWARD_K, INWARD_LINK, INWARD_COS = 16, 4.0, 0.5
#: Samples so found are turned in pieces (`pieces`) of INWARD_MIN samples or more.
INWARD_MIN = 30


def inward_samples(
    points, normals, spacing: float, wtree: WindingTree, tree=None, readings=None
) -> np.ndarray:
    """Which samples' normals point into the solid, part by part: the median winding number of
    all the samples, read over each sample's neighbours that face its way (its part's sheet, not
    a crossing or touching part's), is below -`ORIENT_LEVEL` (`points_inward`, sample by sample).
    An artist's model often has parts whose faces are wound the other way: a closed part turned
    inside out reads about -1/2 at its samples (its own surface gives -1/2, parts it lies outside
    of 0), where a correctly wound one reads +1/2, a cavity's wall +1/2 (-1/2 of its own, +1
    from the solid round it), a patch of a closed surface about +1/2 whichever way it points
    (the rest of the surface gives that), and an open sheet its share of a closed surface (0
    when flat). Left as they are, the inside-out part's volume constraints and off-surface points
    say outside where its inside is. (Sheets of agreeing normals, judged as a whole, merge
    through any contact: an eye that touches the head it sits on faces the head's way there.)

    **Returns:** a boolean mask over the samples (all False when none points in)."""
    p = np.asarray(points, dtype=float)
    nrm = np.asarray(normals, dtype=float)
    n = len(p)
    idx, w = sample_readings(p, wtree) if readings is None else readings
    reach = INWARD_LINK * spacing * np.sqrt(n / len(idx))
    sub = cKDTree(p[idx]) if len(idx) < n else (cKDTree(p) if tree is None else tree)
    ok, safe = _neighbours(sub, p, INWARD_K, reach)
    ok &= np.einsum("ij,ikj->ik", nrm, nrm[idx][safe]) > INWARD_COS
    vals = np.where(ok, w[safe], np.nan)
    with warnings.catch_warnings():  # a sample with no neighbour facing its way: no reading
        warnings.simplefilter("ignore", RuntimeWarning)
        score = np.nanmedian(vals, axis=1)
    # ... and, where read, the sample's own w is below 0 too: a sample beside a touching part
    # that faces its way there reads its own side (a sphere's samples where an inside-out one
    # touches it: 0.35-0.49, their neighbours' median below -0.1)
    own = np.full(n, -np.inf)
    own[idx] = w
    inward = (np.nan_to_num(score, nan=0.0) < -ORIENT_LEVEL) & (own < 0)
    if inward.any():
        # whole parts only: a few samples that read low on their own (a thin part's sides, a
        # crease) are trusted as given
        found = np.flatnonzero(inward)
        label = pieces(p[found], spacing)
        inward[found] = np.bincount(label)[label] >= INWARD_MIN
    return inward


def contradicted(points, outside, wtree: WindingTree, tested: int | None = None) -> np.ndarray:
    """Which off-surface points (`points` (m, 3), `outside` (m,) True for those placed along
    their sample's normal) lie where the winding number `wtree` clearly says the other side:
    w > 1/2 + `RAMP` for an outside point, w < 1/2 - `RAMP` for an inside one. Within `RAMP` of
    1/2 (beside a hole, past an open boundary) w gives no side, and the point is not judged.

    Cost: one w per point (2 s per 40,000 points on 2 cores at 100,000 samples, ten times that
    at 1M: the far field is a sum over the tree's groups, whose count grows with the samples).
    Beyond `tested` points (default
    `CONTRADICTED_TESTED`) a random subset of that size is judged first, then the points near
    those found, and so on while more are found, as `buried_samples` does: what pulls a surface
    out of shape is a cluster of such points (a fin, a hidden face), which a subset of 1 in 10
    still hits; a lone one at that density moves the surface by a fraction of a spacing."""
    q = np.asarray(points, dtype=float)
    out = np.asarray(outside, dtype=bool)
    tested = CONTRADICTED_TESTED if tested is None else int(tested)

    def judge(idx: np.ndarray) -> np.ndarray:
        w = winding_number(q[idx], None, None, tree=wtree)
        return idx[np.where(out[idx], w > 0.5 + RAMP, w < 0.5 - RAMP)]

    return _found_from_subset(q, judge, tested)


def _found_from_subset(points, judge, tested: int, reach: float | None = None) -> np.ndarray:
    """Which of `points` `judge` (indices in, the indices it finds out) finds: it judges all of
    them up to `tested` points; beyond, a random subset of that size, then the points within
    `reach` (default: twice the subset's median spacing) of those found, and so on while more
    are found. What is sought comes in clusters (a buried wall, a fin), which a subset still
    hits."""
    hits = np.zeros(len(points), dtype=bool)
    if len(points) <= tested:
        hits[judge(np.arange(len(points)))] = True
        return hits
    done = np.zeros(len(points), dtype=bool)
    todo = np.random.default_rng(0).choice(len(points), tested, replace=False)
    if reach is None:
        reach = 2.0 * float(np.median(cKDTree(points[todo]).query(points[todo], k=2)[0][:, 1]))
    while len(todo):
        done[todo] = True
        found = judge(todo)
        hits[found] = True
        if len(found) == 0:
            break
        near = cKDTree(points[found]).query(points, distance_upper_bound=reach)[0] < reach
        todo = np.flatnonzero(near & ~done)
    return hits


def buried_samples(
    points, normals, spacing: float, wtree: WindingTree, tree: cKDTree | None = None
) -> np.ndarray:
    """Which samples are buried: w reads inside (above `BURIED_LEVEL`) `BURIED_SPACINGS`
    spacings out along the sample's normal and as far in against it. Such a sample lies inside
    the solid on both of its sides: a wall inside another piece (where a teapot's spout pierces
    its body, an eyeball sunk in its socket, a scan's inner layer). The closed surface the fit
    makes cannot pass through it without a bubble (f would be 0 there and negative on both sides),
    so the fit leaves it out, and closes the pieces' union as Poisson's indicator does.

    Each reading stops halfway to a face turned back towards the sample that lies nearer
    (`BURIED_GAP`, `_face_ahead`): 4 spacings out, a reading crosses a narrow gap of air into
    the part beyond (a cable lying on a base: the base's face under it read inside on both
    sides, was left out, and the surface dented there), or crosses a thin part whole into the
    air (a rod sunk in a plate: its wall inside the plate read outside behind it and was
    fitted). Made cable on a base (10k samples): 64 -> 78 buried, precision at 0.5% 99.77% ->
    99.83%; suzanne 10k 409 -> 341, the cow 10k 131 -> 51 (its tail lies a spacing or two
    off the body).

    Why 4 spacings and 0.6: nearer than a few spacings the sum over discrete samples is rough
    (see `unit_jump`), and on a noisy scan the test fires on the noise. Counted with the
    estimated normals of a virtual range scan of the bunny (150k points, 0.15% noise): 551 of
    the samples read above 1/2 on both sides at 2 spacings, 25 at 3, none at 4. On a teapot
    sampled with its true normals (the spout, an open tube, pierces the body) the count at 4
    spacings is 250 / 238 / 216 for levels 0.5 / 0.6 / 0.7: stable, where at 2 spacings it is
    304 / 243 / 125 (w inside an open tube near its end reads about 0.7).

    Cost: one evaluation of w per sample, a second only behind those that face the inside
    (about 10 s for 150,000 samples on 2 cores). Beyond `BURIED_TESTED` samples, a random
    subset of that size is tested first, then the samples near those found buried, and so on
    while more are found (a buried wall is a stretch of surface, which so many samples see
    whole; on 10,000 samples, a subset of one in 8 missed small clusters: 37 of the teapot's
    238 buried samples, 56 of suzanne's 302). `tree`: a `cKDTree` of `points` to reuse."""
    points = np.asarray(points, dtype=float)
    normals = np.asarray(normals, dtype=float)
    tree = cKDTree(points) if tree is None else tree

    def inside(idx: np.ndarray, sign: float) -> np.ndarray:
        # The reading stops short of a face turned back towards the sample (`BURIED_GAP`):
        # across a narrow gap of air (a cable lying on a plate) the reading 4 spacings out
        # lands inside the other part, and the wall of a thin part is no wider than that.
        gap = _face_ahead(points, normals, idx, spacing, tree, BURIED_SPACINGS, sign, BURIED_GAP)
        reach = np.minimum(BURIED_SPACINGS * spacing, 0.5 * gap)
        at = points[idx] + sign * reach[:, None] * normals[idx]
        return winding_number(at, None, None, tree=wtree) > BURIED_LEVEL

    def test(idx: np.ndarray) -> np.ndarray:
        # most samples face the outside: look behind only those that do not
        idx = idx[inside(idx, 1.0)]
        return idx[inside(idx, -1.0)]

    reach = 2 * np.sqrt(len(points) / BURIED_TESTED) * spacing  # a few subset spacings
    buried = _found_from_subset(points, test, BURIED_TESTED, reach)
    return _buried_to_the_seam(points, spacing, wtree, buried, tree)


def _buried_to_the_seam(points, spacing: float, wtree: WindingTree, buried: np.ndarray, tree):
    """`buried` grown along its walls to where they meet the outer surface: from the buried
    samples, the samples within `BURIED_SPACINGS` spacings whose own w (at the sample, where its
    own sheet gives 1/2) reads above `SEAM_LEVEL`, and on from those while more are found.

    The two-sided test of `buried_samples` looks 4 spacings out, so it stops that far short of
    the seam where a wall meets the outside (an eyeball sunk in its socket, a spout in its body):
    the ring of walls it leaves made bubbles along every seam (suzanne: a ring round each eye,
    NC 0.9523; two spheres and a smaller one sampled whole: 2 components, Chamfer 0.117%). At the
    sample itself w needs no step to read: 1/2 from its own sheet plus what the rest give,
    about 1/2 on the outer surface (up to 0.8 in concave creases; 95% of suzanne's samples read
    below 0.71), 1/2 + 1 on a wall inside a closed piece and about 1.1 inside suzanne's open head.
    Grown only from walls the two-sided test found, it cannot fire where there are none (a
    closed scan's noise)."""
    if not buried.any():
        return buried
    reach = BURIED_SPACINGS * spacing
    tree = cKDTree(points) if tree is None else tree
    tested = buried.copy()
    front = np.flatnonzero(buried)
    while len(front):
        near = tree.query_ball_point(points[front], reach, workers=-1, return_sorted=False)
        near = np.unique(np.concatenate(near).astype(np.int64))
        near = near[~tested[near]]
        if len(near) == 0:
            break
        tested[near] = True
        front = near[np.asarray(winding_number(points[near], None, None, tree=wtree)) > SEAM_LEVEL]
        buried[front] = True
    return buried


_CORNERS = np.array(np.meshgrid(*[[0, 1]] * 3, indexing="ij")).reshape(3, -1).T  # (8, 3)
_EDGES = np.array(
    [(a, b) for a in range(8) for b in range(a + 1, 8) if np.sum(_CORNERS[a] != _CORNERS[b]) == 1]
)  # the 12 edges of a cell, as corner pairs
_NEIGHBOURS = np.array(np.meshgrid(*[[-1, 0, 1]] * 3, indexing="ij")).reshape(3, -1).T


def _pack(keys: np.ndarray) -> np.ndarray:
    """One int64 per lattice index triple (each within +/- 2^20)."""
    k = keys.astype(np.int64) + (1 << 20)
    return (k[..., 0] << 42) | (k[..., 1] << 21) | k[..., 2]


#: `_out_of_walls`: the samples within WALL_REACH spacings of a closing sample that tell a
#: wall, and the widest gap (radians) in the directions to them, seen along the wall.
WALL_REACH, WALL_GAP = 6.0, np.pi / 2


def _out_of_walls(x, xn, points, normals, spacing: float, tree: cKDTree):
    """The closing samples `x` (normals `xn`) that do not lie inside a thin wall: in a gap of
    the random samples of a closed wall 3-4 spacings thick, a point can lie 3 spacings from
    every sample with w near its level there (0.6-0.8 inside such a wall), and a closing
    sample (f = 0) there grows a bubble out of the wall (a made cup: 14 of them, bubbles 2% of
    the diagonal). Such a point lies behind samples within `WALL_REACH` spacings that face
    opposite ways (the wall's two faces), and seen along their normal those samples surround
    it (no gap in its directions wider than `WALL_GAP`); over a hole or a tube's open end they
    lie to one side."""
    if len(x) == 0:
        return x, xn
    keep = np.ones(len(x), dtype=bool)
    for i, near in enumerate(tree.query_ball_point(x, WALL_REACH * spacing, workers=-1)):
        q, m = points[near], normals[near]
        behind = np.einsum("ij,ij->i", x[i] - q, m) < 0
        q, m = q[behind], m[behind]
        if len(q) < 8 or np.min(m @ m.T) > -0.5:
            continue
        u, v = (e[0] for e in tangent_frames(m[:1]))
        rel = q - x[i]
        keep[i] = widest_gap(np.sort(np.arctan2(rel @ v, rel @ u))) > WALL_GAP
    return x[keep], xn[keep]


def closing_samples(points, seeds, spacing: float, wtree: WindingTree, tree: cKDTree, level=None):
    """Oriented samples of the winding number's closing surface, the level w = 1/2 (or the
    surface's own `level`, a `ClosingLevel`: `closing_level`), where it lies at least
    `CLOSE_CLEAR` spacings from every sample: over holes, past open boundaries, between the
    pieces of a soup. There the data say nothing, and w = 1/2 is the surface that screened
    Poisson's indicator would close with (w is the harmonic field of the samples' dipoles): a
    membrane across a hole, flat where the rim is, with no slope carried on from the rim's
    neighbourhood. Given to the fit as ordinary samples, they make it close there and only there.

    From `seeds` (points where w is near the level, such as the undecided probes), each moved
    onto it by Newton steps along grad w, the cells of a lattice of `CLOSE_CELL` spacings that w
    crosses the level in are grown across the level from neighbour to neighbour (surface tracking
    on the lattice: w is evaluated at the cells' corners only), and stop where the level comes
    within `CLOSE_CLEAR` spacings of the samples (there it runs into the sampled surface, which
    w passes its level on as well). Each crossed cell gives one sample: the mean of its edges'
    crossings, moved onto the level by one Newton step, with the outward normal -grad w / |grad w|.

    **Returns:** `(samples, normals)`, (m, 3) arrays (m may be 0)."""
    h = CLOSE_CELL * spacing
    clear = CLOSE_CLEAR * spacing
    level = ClosingLevel() if level is None else level
    lo, hi = _probe_box(points)
    dims = np.ceil((hi - lo) / h).astype(np.int64)
    empty = (np.zeros((0, 3)), np.zeros((0, 3)))
    x = np.asarray(seeds, dtype=float).reshape(-1, 3)
    for _ in range(3):  # Newton steps onto the level, each at most a few cells long
        if len(x) == 0:
            return empty
        w, g = winding_number(x, None, None, tree=wtree, gradient=True)
        x = _newton_step(x, w, g, level(x), 4 * h, np)
        x = x[np.all((x > lo) & (x < hi), axis=1)]
    if len(x) == 0:
        return empty
    active = np.unique(np.floor((x - lo) / h).astype(np.int64), axis=0)
    seen = set(_pack(active).tolist())
    values: dict[int, float] = {}
    found, looked = [], 0
    while len(active) and looked < CLOSE_MAX_CELLS:
        looked += len(active)
        corners = active[:, None, :] + _CORNERS[None]  # (m, 8, 3)
        keys = _pack(corners)
        flat = np.unique(keys)
        new = np.array([k not in values for k in flat.tolist()], dtype=bool)
        if new.any():
            k = flat[new]
            ijk = np.stack([(k >> 42) & 0x1FFFFF, (k >> 21) & 0x1FFFFF, k & 0x1FFFFF], 1)
            xk = lo + (ijk - (1 << 20)) * h
            wk = winding_number(xk, None, None, tree=wtree) - level(xk)
            values.update(zip(k.tolist(), wk.tolist(), strict=True))
        s = np.array([values[k] for k in keys.ravel().tolist()]).reshape(keys.shape)
        crossed = (s.min(axis=1) < 0) & (s.max(axis=1) > 0)
        cells, s = active[crossed], s[crossed]
        if len(cells) == 0:
            break
        a, b = s[:, _EDGES[:, 0]], s[:, _EDGES[:, 1]]  # (m, 12)
        cut = (a < 0) != (b < 0)
        t = np.where(cut, a / np.where(cut, a - b, 1.0), 0.0)
        ends = lo + (cells[:, None, None, :] + _CORNERS[_EDGES][None]) * h  # (m, 12, 2, 3)
        pts = ends[:, :, 0] + t[..., None] * (ends[:, :, 1] - ends[:, :, 0])
        centre = np.sum(pts * cut[..., None], axis=1) / np.sum(cut, axis=1, keepdims=True)
        dist, _ = tree.query(centre, workers=-1, distance_upper_bound=clear)
        far = dist >= clear
        found.append(centre[far])
        # grow across the level from the cells clear of the samples
        grow = (cells[far][:, None, :] + _NEIGHBOURS[None]).reshape(-1, 3)
        grow = grow[np.all((grow >= 0) & (grow < dims), axis=1)]
        grow = np.unique(grow, axis=0)
        packed = _pack(grow)
        fresh = np.array([k not in seen for k in packed.tolist()], dtype=bool)
        active = grow[fresh]
        seen.update(packed[fresh].tolist())
    if not found:
        return empty
    x = np.concatenate(found)
    if len(x) == 0:
        return empty
    w, g = winding_number(x, None, None, tree=wtree, gradient=True)
    g2 = np.maximum(np.sum(g * g, axis=1), 1e-300)
    step = ((w - level(x)) / g2)[:, None] * g
    ok = np.linalg.norm(step, axis=1) < h  # a cell's mean crossing is within a cell of the level
    x = x[ok] - step[ok]
    n = -g[ok] / np.sqrt(g2[ok])[:, None]
    dist, _ = tree.query(x, workers=-1, distance_upper_bound=clear)
    keep = dist >= clear
    return x[keep], n[keep]


#: Closing samples nearer than this many lattice cells belong to one closing surface.
CLOSE_LINK = 1.8


def closing_areas(normals: np.ndarray, spacing: float) -> np.ndarray:
    """The area each closing sample stands for. `closing_samples` gives one sample per lattice
    cell (side h = `CLOSE_CELL` spacings) its level crosses, and a plane of unit normal n
    crosses (|n_x| + |n_y| + |n_z|) / h^2 cells per unit area: each sample stands for
    h^2 / |n|_1. (The samples' own density, `sample_areas`, would not do: a closing piece of
    a few samples weighs each like a disc reaching to its distant neighbours, and that made
    a teapot's lid gap, whose closing is 2 samples, grow a 354-sample sheet.)"""
    h = CLOSE_CELL * spacing
    return h * h / np.maximum(np.sum(np.abs(normals), axis=1), 1.0)


def reclosed(points, normals, areas, closing, spacing: float):
    """The closing surfaces of holes again, each with the others closed: every connected piece
    of `closing` (samples nearer than `CLOSE_LINK` lattice cells) that closes a hole (one that
    stays `CLOSE_LINK` cells inside the probes' box) is sampled anew on the level w = 1/2 of the
    samples and the other holes' closing samples together. Alone, w of an input with several
    holes reads well under 1 inside (a car body open underneath: about 0.7), and each hole's
    level 1/2 bows into the solid; with the other holes closed, w inside is about 1 again and
    each closes across its rim. A piece that runs into the box (past the edge of an open scan,
    a sheet) closes no hole: it is left as it is and closes nothing for the others (re-closed
    with it, the open real leg scan grew 12,000 more closing samples and 12% more surface far
    from its points).

    **Returns:** `(samples, normals, held)`, `held` marking the samples of re-closed holes (all
    False, and `closing` as given, with fewer than two holes)."""
    from ._prepare import linked_groups

    c, cn = closing
    h = CLOSE_CELL * spacing
    none = (c, cn, np.zeros(len(c), dtype=bool))
    if len(c) < 2:
        return none
    count, label = linked_groups(c, CLOSE_LINK * h)
    lo, hi = _probe_box(points)
    edge = np.any((c < lo + CLOSE_LINK * h) | (c > hi - CLOSE_LINK * h), axis=1)
    hole = np.bincount(label[edge], minlength=count) == 0
    if np.sum(hole) < 2:
        return none
    held = hole[label]
    # the samples and the held closing samples (weighted by `closing_areas`) in one tree, each
    # hole's own left out of it in turn by `_without`
    whole, slots = _indexed_tree(
        np.concatenate([points, c[held]]),
        np.concatenate([normals, cn[held]]),
        np.concatenate([areas, closing_areas(cn[held], spacing)]),
    )
    tag = np.concatenate([np.full(len(points), -1), label[held]])
    out, out_n, out_held = [c[~held]], [cn[~held]], [np.zeros(np.sum(~held), dtype=bool)]
    for k in np.flatnonzero(hole):
        # the walk stops short of the other closings too: across them w jumps as it does across
        # the samples, and past a small piece near a larger one it grew a copy of the larger's
        # closing, half its normals the wrong way (an open sphere: 1,893 samples for 945)
        clear = cKDTree(np.concatenate([points, c[held & (label != k)]]))
        x, xn = closing_samples(
            points, c[label == k], spacing, _without(whole, slots, tag == k), clear
        )
        out.append(x)
        out_n.append(xn)
        out_held.append(np.ones(len(x), dtype=bool))
    return np.concatenate(out), np.concatenate(out_n), np.concatenate(out_held)


def calibrated_areas(points, normals, *, tree=None, spacing=None, rim=None) -> np.ndarray:
    """The area weights `winding_number` and `volume_constraints` use by default:
    `sample_areas`, halved on the boundary samples (`rim`, default
    `jaxrbf._holes.boundary_mask`: a rim sample's k neighbours fill a half-disc; uncorrected,
    the rim of an open hemisphere weighs double and w on its closing disc reads 0.52, so the cap
    sags by 4% of the radius), then divided by `unit_jump`."""
    tree = cKDTree(points) if tree is None else tree
    spacing = point_spacing(points) if spacing is None else spacing
    rim = boundary_mask(points, normals, tree=tree) if rim is None else rim
    areas = sample_areas(points, tree=tree)
    areas[rim] *= 0.5
    wtree = winding_tree(points, normals, areas)
    return areas / unit_jump(points, normals, spacing, wtree, near=tree)


def unit_jump(
    points, normals, spacing: float, tree: WindingTree, seed: int = 0, near: cKDTree | None = None
) -> float:
    """The jump of w across the sampled surface, taken to zero distance: J(t) = median of
    w(p - t n) - w(p + t n) over up to `JUMP_SAMPLES` samples, at t = `JUMP_SPACINGS` and twice
    that, extrapolated linearly to t = 0 (2 J(t) - J(2t)). At t -> 0 the jump is exactly one
    turn for exact area weights, on any surface, closed or not; at a finite t an open surface's
    missing part adds a term linear in t (on an open hemisphere of 1,500 samples, J = 0.90 at 4
    spacings and 0.82 at 8: the extrapolation gives 0.98), and nearer than a few spacings the
    sum over discrete samples is too rough to tell. `sample_areas` errs by the sampling's
    irregularity: this reads 1.0 on uniform samples of a mesh, 1.2 on a noisy, misregistered
    range scan (whose w then reads 1.1 inside, and whose holes' caps, where w = 1/2, sag by a
    few tenths of a percent of the diagonal). Clipped to [1/2, 2].

    Samples whose readings cross another face count not (`near`, a k-d tree of `points`): with
    a face turned the other way within 2 t behind them (`_backed`) or in front: across a closed
    part thinner than 2 t the far reading lies outside again, J(2t) reads about 0 and the
    extrapolation doubled J(t) (a made chair of boxes 4-5 spacings thick: 1.62, so that w read
    0.6 inside its seat, which was then taken for an open sheet and thickened: NC 0.881
    against Poisson's 0.941). Where most samples are such (`BACKED_SHARE`: a thin-walled
    object, whose other samples lie on its parts' narrow sides, between two faces: the chair's
    read 0.81), or fewer than `JUMP_MIN_CLEAR` are not, the weights are taken as they are (1).
    (Keeping only samples all of whose readings lie clear of every sample, `NEAR_CLEAR`, read
    1.13 instead of 1.19 on virtual scans, and cost the fandisk scan 0.004% of Chamfer-L1.)"""
    near = cKDTree(points) if near is None else near
    rng = np.random.default_rng(seed)
    pick = rng.permutation(len(points))[: JUMP_TRIED * JUMP_SAMPLES]
    steps = int(np.ceil(2 * JUMP_SPACINGS))
    across = _backed(points, normals, pick, spacing, near, steps, -1.0)
    across |= _backed(points, normals, pick, spacing, near, steps, 1.0)
    if np.mean(across) > BACKED_SHARE:
        return 1.0
    pick = pick[~across][:JUMP_SAMPLES]
    if len(pick) < JUMP_MIN_CLEAR:
        return 1.0
    jumps = []
    for t in (JUMP_SPACINGS, 2 * JUMP_SPACINGS):
        step = t * spacing * normals[pick]
        inner = winding_number(points[pick] - step, None, None, tree=tree)
        outer = winding_number(points[pick] + step, None, None, tree=tree)
        jumps.append(float(np.median(inner - outer)))
    return float(np.clip(2 * jumps[0] - jumps[1], 0.5, 2.0))


def rim_probes(rim: np.ndarray, spacing: float, reach: float, tree: cKDTree) -> np.ndarray:
    """Probes around the boundary samples `rim` (where the sampled surface stops: a hole's rim,
    a sheet's edge): a lattice of `RIM_CELL` spacings within `reach` of a rim sample, at least
    `RIM_SHELL` lattice steps from every sample. The octree's shells start 1.5 finest cells (9
    spacings) out; without these, the fit extrapolates the surface past a rim for that far
    (a tube's open end closes in a rounded bulb beyond it, not across it)."""
    if len(rim) == 0:
        return np.zeros((0, 3))
    step = RIM_CELL * spacing
    m = int(np.ceil(reach / step))
    grid = np.stack(np.meshgrid(*[np.arange(-m, m + 1)] * 3, indexing="ij"), -1).reshape(-1, 3)
    grid = grid[np.sum(grid**2, axis=1) * step**2 <= reach**2]
    base = np.unique(np.round(rim / step).astype(np.int64), axis=0)
    keys = np.unique((base[:, None, :] + grid[None]).reshape(-1, 3), axis=0)
    probes = keys * step
    dist, _ = tree.query(probes, workers=-1, distance_upper_bound=reach)
    return probes[(dist >= RIM_SHELL * step) & (dist < reach)]


def shell_probes(points, normals, spacing: float, tree: cKDTree) -> tuple[np.ndarray, np.ndarray]:
    """Probes between the off-surface points (2 spacings out) and the octree's finest shell (9
    spacings and more): `NEAR_SPACINGS` spacings out along and against the normal of one sample
    per lattice cell of that size, kept where no sample is nearer than `NEAR_CLEAR` of that
    distance (not across a thin part). In that gap nothing else holds the fit, and a
    partition's patches can blend into a closed blob a few spacings off the surface (one sat on
    the rim of a teapot's lid knob, 3 spacings out, where a false boundary's rim probes had
    happened to hold it).

    **Returns:** `(probes, out)`: the probes, and True for those along the normal (outside)."""
    reach = NEAR_SPACINGS * spacing
    # one sample per cell and normal octant: both sides of a thin part get theirs
    key = np.column_stack([np.floor(points / reach).astype(np.int64), normals > 0])
    _, pick = np.unique(key, axis=0, return_index=True)
    pick = np.sort(pick)
    step = reach * normals[pick]
    base = points[pick]
    probes = np.concatenate([base + step, base - step])
    out = np.arange(len(probes)) < len(base)
    dist, _ = tree.query(probes, workers=-1)
    ok = np.flatnonzero(dist >= NEAR_CLEAR * reach)
    # then one probe per cell of 1.5 times that size: a curved patch's samples span several
    # octants, whose probes land side by side (60,817 probes for 100k samples of the bunny)
    _, first = np.unique(
        np.floor(probes[ok] / (1.5 * reach)).astype(np.int64), axis=0, return_index=True
    )
    ok = ok[np.sort(first)]
    return probes[ok], out[ok]


class ClosingLevel:
    """The level of w that the surface passes through, as a field: the mid-values `levels`
    measured at the `sites` (`closing_level`), carried between them as the median of the
    `LEVEL_NEIGHBOURS` nearest (a median, not a weighted mean: one site reading a thin part or
    a crease does not pull the level of a whole patch). With no sites it is 1/2 everywhere."""

    def __init__(self, sites: np.ndarray | None = None, levels: np.ndarray | None = None):
        self.sites = np.zeros((0, 3)) if sites is None else np.asarray(sites, dtype=float)
        self.levels = np.zeros(0) if levels is None else np.asarray(levels, dtype=float)
        self._tree = cKDTree(self.sites) if len(self.sites) else None

    def __call__(self, x) -> np.ndarray:
        x = np.asarray(x, dtype=float).reshape(-1, 3)
        if self._tree is None or len(x) == 0:
            return np.full(len(x), 0.5)
        k = min(LEVEL_NEIGHBOURS, len(self.sites))
        _, i = self._tree.query(x, k=k, workers=-1)
        return np.median(self.levels[i.reshape(len(x), k)], axis=1)


def closing_level(
    points, normals, spacing: float, wtree: WindingTree, tree: cKDTree, use=None, seed: int = 0
) -> ClosingLevel:
    """Where the sampled surface passes between w's inside and outside values: at a sample p with
    normal n, the mid-value (w(p + t n) + w(p - t n)) / 2 at t = `JUMP_SPACINGS` spacings (w
    jumps by one turn across the surface, so this is the level the surface itself stands on).
    It is 1/2 on a closed surface; where the surface is open it is not: about 0.6 at the mouth
    of a partly enclosed pocket that no view of a scan saw (more of the surface surrounds it),
    about 0.4 at the rim of a hole in a convex part. The level w = 1/2 then closes a pocket
    across its mouth and a hole flat across its rim; closed on this level instead, a closing
    continues the surface around it the way the truth does (measured on a virtual scan of spot:
    on its unseen true surface w - 1/2 has median 0.04 and quartiles -0.004 / 0.10, w minus
    this level (as the median of 128 sites) 0.006). Read at up to `LEVEL_SAMPLES` samples
    (those `use` marks), where neither reading has another sample within `NEAR_CLEAR` of t
    (not across a thin part: there the far reading is outside again), clipped to
    `LEVEL_CLIP`."""
    p = np.asarray(points, dtype=float)
    n = np.asarray(normals, dtype=float)
    cand = np.flatnonzero(np.ones(len(p), dtype=bool) if use is None else use)
    if len(cand) > LEVEL_SAMPLES:
        cand = np.sort(np.random.default_rng(seed).choice(cand, LEVEL_SAMPLES, replace=False))
    if len(cand) == 0:
        return ClosingLevel()
    t = JUMP_SPACINGS * spacing
    out, inn = p[cand] + t * n[cand], p[cand] - t * n[cand]
    d_out, _ = tree.query(out, workers=-1)
    d_in, _ = tree.query(inn, workers=-1)
    ok = (d_out >= NEAR_CLEAR * t) & (d_in >= NEAR_CLEAR * t)
    if not ok.any():
        return ClosingLevel()
    w = winding_number(np.concatenate([out[ok], inn[ok]]), None, None, tree=wtree)
    m = int(np.sum(ok))
    mid = np.clip(0.5 * (w[:m] + w[m:]), *LEVEL_CLIP)
    return ClosingLevel(p[cand[ok]], mid)


def signed_values(w: np.ndarray, grad: np.ndarray, dist: np.ndarray, level=0.5) -> np.ndarray:
    """The value of a probe with winding number `w` (gradient `grad`) at `dist` from the nearest
    sample: positive outside (w < `level`, 1/2 or the surface's own closing level per probe),
    negative inside, and in magnitude the smaller of `dist` and |w - level| / |grad w|, the
    first-order distance to the closing surface w = level. Near the data the
    two agree; over a hole or past an open boundary the second is the distance to the winding
    number's own closing surface (which spans a hole like a membrane: on the disc that closes an
    open hemisphere, w = 1/2), so the fit crosses zero there with the same unit slope as at its
    samples. Far from everything, w is flat and `dist` is the smaller."""
    gap = np.abs(level - w) / np.maximum(np.linalg.norm(grad, axis=1), 1e-300)
    return np.where(w < level, 1.0, -1.0) * np.minimum(dist, gap)
