"""Interpolation constraints (paper §3): on-surface points with value 0 and off-surface points at
+d (outside) and -d (inside) along the normals, so that the system is not homogeneous."""

from __future__ import annotations

import itertools
import sys

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._errors import InputError
from ._prepare import (
    diagonal,
    duplicate_pairs,
    find_duplicates,
    polyline_normals,
    sample_faces,
    vertex_normals,
)
from ._util import log as log  # re-exported: the package's one stderr logger
from .io import as_points

#: Default offset d as a fraction of the bounding-box diagonal.
DEFAULT_OFFSET = 0.01
#: Points closer than this fraction of the diagonal are merged.
MERGE_TOL = 1e-6
_SHRINK_STEPS = 8
#: Each sample stands for the surface around it out to its `_PATCH_K`-th nearest neighbour
#: (about 2.5 nearest-neighbour spacings for even sampling: the size of the gaps that random
#: sampling leaves), bent by the curvature those neighbours show.
_PATCH_K = 6
#: An off-surface point nearer than this fraction of its offset to another sample's patch is
#: shrunk: f would have to change by the offset over less than half of it, and a linear or
#: cubic interpolant overshoots to do so.
_PATCH_CLEAR = 0.5
#: Neighbours whose normals are within 30 degrees lie on the sample's own face: its curvature is
#: taken from them (a crease's other face would read as a very sharp bend), and a sample with
#: fewer than two of them (a lone point on a crease) stands for no patch.
_SAME_FACE_COS = float(np.cos(np.radians(30.0)))
#: Neighbours of each off-surface point whose patches are tested, and points per block.
_PATCH_NEIGHBOURS = 16
_CHUNK = 65536
#: Thin walls and narrow gaps (exact samples only). Where the surface facing back at a sample
#: (the other face of a wall, or across a gap) lies t away along one of its off-surface
#: directions, that off-surface point at offset d is valued d (1 - d (1/t - 1/T)) instead of d,
#: T being this many offsets: the quadratic profile z (t - z) / t, which vanishes on both faces
#: with unit slope there, handed over to the signed distance d as t grows to T. The signed
#: distance folds along the middle of a thin wall, which an interpolant smooths over, and
#: between the samples its surface stood out of the wall. Measured on hollow spheres (10,000
#: samples with normals, default fit; along 4,000 rays, the zero set's mean offset from each
#: face, outer / inner, in point spacings, + out of the wall), with the profile and the
#: shrinking on either side of a facing patch (`_on_another_patch`): a wall 3.8 spacings thick
#: +0.066 / +0.077 (rms 0.11) -> +0.002 / +0.014 (rms 0.086 / 0.070), a thick sphere (27
#: spacings) unchanged. With, besides, boundaries judged by the neighbours on a point's own
#: side (`jaxrbf._holes`) and the finest level holding the probes' shell
#: (`jaxrbf._partition.VOLUME_FAR_FINEST`): wall 2.7 spacings +0.150 / +0.177 (rms 0.22 /
#: 0.24) -> +0.003 / +0.009 (0.078 / 0.074); 3.8 spacings -> +0.022 / +0.031 (0.063 / 0.067);
#: the thick sphere -0.001 / +0.002 (0.008 / 0.011) -> -0.003 / +0.005 (0.009 / 0.012).
_FACING_REACH = 6.0


def _unit_normals(normals: np.ndarray, n: int, dim: int) -> np.ndarray:
    normals = as_points(normals, "normals", (dim,))
    if len(normals) != n:
        raise InputError(
            f"`normals` has {len(normals)} rows but `points` has {n}; give one normal per point"
        )
    length = np.linalg.norm(normals, axis=1)
    zero = length <= 1e-12 * max(float(length.max()), 1e-300)
    if zero.any():
        raise InputError(
            f"`normals` has {int(zero.sum())} zero-length vectors (first: row {int(np.argmax(zero))}); "
            "every point needs a direction to place its off-surface points"
        )
    return normals / length[:, None]


def checked_samples(points, normals) -> tuple[np.ndarray, np.ndarray]:
    """Surface samples as float64 host arrays, checked (finite points, one finite nonzero normal
    per point, the same dimension), the normals made unit: `(points, normals)`."""
    p = as_points(points, "points")
    return p, _unit_normals(normals, len(p), p.shape[1])


def duplicate_pairs_checked(p: np.ndarray, nrm: np.ndarray, tol: float) -> np.ndarray:
    """The pairs of points closer than `tol` (`duplicate_pairs`), refused when a pair's unit
    normals disagree: one place cannot be both inside and outside."""
    pairs = duplicate_pairs(p, tol)
    clash = pairs[np.sum(nrm[pairs[:, 0]] * nrm[pairs[:, 1]], axis=1) < 0.5]
    if len(clash):
        i, j = (int(k) for k in clash[0])
        raise InputError(
            f"points {i} and {j} are identical but their normals disagree ({len(clash)} such "
            "pairs): one place cannot be both inside and outside; remove one of each pair"
        )
    return pairs


def _patches(tree, p: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each sample's patch for `_validated_offsets`: its reach (the distance to its `_PATCH_K`-th
    neighbour), its curvature (the median over its neighbours on the same face of the bend
    -2 h / t^2 that each shows over its tangent plane) and whether it has one (at least two
    neighbours on its face)."""
    dist, idx = tree.query(p, k=min(_PATCH_K + 1, len(p)), workers=-1)
    rel = p[idx[:, 1:]] - p[:, None, :]
    h = np.einsum("kmd,kd->km", rel, n)
    t2 = np.maximum(np.einsum("kmd,kmd->km", rel, rel) - h * h, 1e-300)
    same = np.einsum("kmd,kd->km", n[idx[:, 1:]], n) > _SAME_FACE_COS
    has = same.sum(axis=1) >= 2
    kappa = np.zeros(len(p))
    kappa[has] = np.nanmedian(np.where(same, -2.0 * h / t2, np.nan)[has], axis=1)
    return dist[:, -1], kappa, has


def _on_another_patch(q, t, idx, d, p, n, reach, kappa, has, sign: float) -> np.ndarray:
    """Which off-surface points `q` (of samples `t`, offsets `d`, on the side `sign` of their
    samples) lie nearer than `_PATCH_CLEAR` of their offset to the patch of a neighbour `idx`
    other than their own origin, or less than their offset from the patch of one turned back
    towards their sample (normals' cosine below -1/2), on either side of it. Behind it: across
    a crevice between two parts (a cable lying on a base, its underside a spacing or two above
    the base's face), an outside point crosses the other face through a gap in its random
    samples, where the first test looks within half the offset only. In front of it: inside a
    wall thinner than two offsets (or in a gap as narrow), the value d would overstate the
    point's distance to the surface, and the samples of the other face, a random few
    spacings apart, often leave none nearer than d to catch it: a hollow sphere with a wall
    2.7 spacings thick (10,000 samples, offset 1.55 spacings) kept half of its inside points at
    -d 1.13 spacings from the other face, and its surface stood 0.15 spacings out of the wall
    on average (rms 0.22 spacings); tested on both sides, every one is shrunk: 0.025 (0.12)."""
    rel = q[:, None, :] - p[idx]
    h = np.einsum("kmd,kmd->km", rel, n[idx])
    t2 = np.maximum(np.einsum("kmd,kmd->km", rel, rel) - h * h, 0.0)
    height = h + 0.5 * kappa[idx] * t2
    hit = (idx != t[:, None]) & has[idx] & (t2 <= reach[idx] ** 2)
    near = np.abs(height) < _PATCH_CLEAR * d[:, None]
    back = np.einsum("kmd,kd->km", n[idx], n[t]) < -0.5
    facing = back & (np.abs(height) < d[:, None])
    return np.any(hit & (near | facing), axis=1)


def _facing_distance(tree, p, n, offset: float, sign: float, reach, has, todo) -> np.ndarray:
    """For each sample of `p` (normals `n`), the distance along `sign` times its normal to the
    nearest patch (`_patches`: `reach`, `has`) of a sample turned back towards it (normals'
    cosine below -1/2: the other face of a thin wall, or across a narrow gap), looked for out
    to `_FACING_REACH` offsets; inf where there is none, and for the samples not in `todo`
    (`_maybe_facing`, indices). The patches are taken flat here."""
    t = np.full(len(p), np.inf)
    m = min(_PATCH_NEIGHBOURS, len(p))
    for lo in range(0, len(todo), _CHUNK):
        rows = todo[lo : lo + _CHUNK]
        pi, ni = p[rows], n[rows]
        best = t[rows]
        # the neighbours of points along the ray, an offset apart, hold the patches it meets
        for k in range(int(np.ceil(_FACING_REACH))):
            _, idx = tree.query(pi + sign * (k + 0.5) * offset * ni, k=m, workers=-1)
            idx = idx.reshape(len(pi), m)
            nj = n[idx]
            cos = np.einsum("kmd,kd->km", nj, ni)
            back = (cos < -0.5) & has[idx]
            along = np.einsum("kmd,kmd->km", p[idx] - pi[:, None, :], nj)
            s = np.where(back, along / np.where(back, sign * cos, -1.0), -1.0)
            meet = pi[:, None, :] + sign * s[..., None] * ni[:, None, :]
            lateral2 = np.sum((meet - p[idx]) ** 2, axis=2)
            ok = back & (s > 0) & (lateral2 <= reach[idx] ** 2)
            best = np.minimum(best, np.where(ok, s, np.inf).min(axis=1))
        t[rows] = best
    return t


def _maybe_facing(p: np.ndarray, n: np.ndarray, reach: float) -> np.ndarray:
    """The samples that may have one turned back towards them (normals' cosine below -1/2)
    within `reach` (indices; a superset): on a grid of cells `reach` wide, those whose normal
    has a cosine that low with one allowed by the bounds of the normals' components over the
    3^d cells around theirs. Most samples of thick parts have none, and skip the ray tests."""
    key = np.floor((p - p.min(axis=0)) / reach).astype(np.int64) + 1
    dims = key.max(axis=0) + 2
    if float(np.prod(dims.astype(float))) >= 2.0**62:  # cells too many to number: test all
        return np.arange(len(p))
    stride = np.cumprod(np.concatenate([dims[1:], [1]])[::-1])[::-1]
    cells, inverse = np.unique(key @ stride, return_inverse=True)
    lo = np.full((len(cells), p.shape[1]), np.inf)
    hi = np.full((len(cells), p.shape[1]), -np.inf)
    np.minimum.at(lo, inverse, n)
    np.maximum.at(hi, inverse, n)
    near_lo, near_hi = lo.copy(), hi.copy()
    for step in itertools.product((-1, 0, 1), repeat=p.shape[1]):
        other = cells + np.asarray(step) @ stride
        at = np.minimum(np.searchsorted(cells, other), len(cells) - 1)
        found = cells[at] == other
        near_lo[found] = np.minimum(near_lo[found], lo[at[found]])
        near_hi[found] = np.maximum(near_hi[found], hi[at[found]])
    lowest = np.minimum(n * near_lo[inverse], n * near_hi[inverse]).sum(axis=1)
    return np.flatnonzero(lowest < -0.5)


def _facing_values(d: np.ndarray, t: np.ndarray, offset: float) -> np.ndarray:
    """The magnitudes of off-surface values at offsets `d` whose surface faces back `t` away
    along them (`_facing_distance`): d (1 - d (1/t - 1/T)), T = `_FACING_REACH` offsets, at
    least d / 2 (see `_FACING_REACH`)."""
    share = d * np.maximum(1.0 / t - 1.0 / (_FACING_REACH * offset), 0.0)
    return d * (1.0 - np.minimum(share, 0.5))


def _validated_offsets(
    p: np.ndarray, n: np.ndarray, offset: float, sign: float, tree, patches
) -> np.ndarray:
    """Carr et al. (2001): shrink each off-surface offset until the nearest input point of the
    off-surface point is its own origin; NaN marks points that never get there (dropped).

    Samples are points, and a gap between them (random samples leave gaps of 2-3 spacings) lets
    an off-surface point pass that test while the unsampled surface lies much closer to it than
    its offset: f then has to fall from +d to 0 over a fraction of d, and the surface dents in
    by about d (measured on the fandisk's narrow strips). So each sample also stands for the
    surface around it out to its `_PATCH_K`-th neighbour: its tangent plane bent by the median
    normal curvature of its neighbours on the same face (a paraboloid, so that a curved
    surface's patches do not stick out of it and a sphere's offsets stay whole), and an offset
    point whose height over another sample's patch is under `_PATCH_CLEAR` of its offset is
    shrunk too. `tree` is a k-d tree of `p`, `patches` the samples' patches (`_patches`), or
    None to leave that second test out: a noisy cloud's samples scatter about their surface by
    a good part of the offset, so their patches (and the curvatures they are bent by) are noise
    (measured on virtual range scans)."""
    d = np.full(len(p), float(offset))
    todo = np.arange(len(p))
    m = 1 if patches is None else min(_PATCH_NEIGHBOURS, len(p))
    for _ in range(_SHRINK_STEPS + 1):
        bad = np.zeros(len(todo), bool)
        for lo in range(0, len(todo), _CHUNK):
            t = todo[lo : lo + _CHUNK]
            q = p[t] + sign * d[t, None] * n[t]
            dist, idx = tree.query(q, k=m, workers=-1)
            dist, idx = dist.reshape(len(t), m), idx.reshape(len(t), m)
            near = (idx[:, 0] != t) & (dist[:, 0] < d[t] * (1 - 1e-9))
            if patches is not None:
                near |= _on_another_patch(q, t, idx, d[t], p, n, *patches, sign)
            bad[lo : lo + _CHUNK] = near
        todo = todo[bad]
        if len(todo) == 0:
            break
        d[todo] *= 0.5
    d[todo] = np.nan
    return d


#: A smoothed fit (smoothing > 0: noisy samples, approximated) adds this fraction of its
#: smoothing to the rows of the volume constraints: they carry no sample noise, so it holds
#: them to their values and approximates only the samples. Smoothed with the samples, the local
#: fits sagged between the probes where nothing else speaks (a virtual scan of a cow with
#: scanner normals: lobes of surface 0.8% of the diagonal out below the unseen soles of its
#: hooves and beside its horns; precision at 0.5% 99.82% -> 99.91%, 0.1 of it: 99.90%).
VOLUME_SMOOTHING = 0.0


class Constraints(eqx.Module):
    """Points and the values f must take there.

    **Fields:**
    - `points`: (N, d) constraint locations in the user's units.
    - `values`: (N,) target values (0 on the surface, +/- the offset off it; less inside a
      thin wall or a narrow gap, see `_FACING_REACH`).
    - `n_surface`: how many of the points are on-surface (they come first).
    - `n_shrunk`, `n_dropped`: off-surface points whose offset was shrunk, or that were dropped,
      because they came closer to another part of the surface than to their own origin.
    - `n_volume`: how many of the points (they come last) are volume constraints away from the
      surface, valued by their signed distance to it (`with_volume`, `jaxrbf._winding`). The
      partition of unity gives them to the levels whose patches reach that far, instead of
      building patches on them. A smoothed fit holds them (`VOLUME_SMOOTHING`).
    """

    points: Float[Array, "N d"]
    values: Float[Array, " N"]
    n_surface: int = eqx.field(static=True, default=0)
    n_shrunk: int = eqx.field(static=True, default=0)
    n_dropped: int = eqx.field(static=True, default=0)
    n_merged: int = eqx.field(static=True, default=0)
    n_volume: int = eqx.field(static=True, default=0)

    @classmethod
    def from_points(
        cls,
        points,
        normals,
        offset: float | None = None,
        *,
        validate: bool = True,
        merge_tol: float = MERGE_TOL,
        between: bool = True,
    ) -> Constraints:
        """On-surface points and their outward normals to constraints.

        **Arguments:**
        - `points`: (n, d) on-surface points, d = 2 or 3.
        - `normals`: (n, d) outward normals (any length but zero; they are normalised).
        - `offset`: d, in the points' units; default 1% of the bounding-box diagonal.
        - `validate`: shrink (or drop) off-surface points that land nearer another part of the
          surface than their own origin (Carr et al. 2001); with `between`, also value those
          facing another face of the surface a few offsets away (a thin wall, a narrow gap) by
          a profile that vanishes on both faces (`_FACING_REACH`) instead of their offset.
        - `merge_tol`: points closer than this fraction of the diagonal are merged.
        - `between`: validate against the surface between the samples too (each sample's patch
          of tangent plane, bent by its neighbours' curvature), not only against the samples;
          meant for samples that lie on their surface (False for a noisy cloud).

        **Returns:** `Constraints` with the n on-surface points first, then the outside points
        (value +d), then the inside points (value -d).
        """
        p = as_points(points, "points")
        nrm = _unit_normals(normals, len(p), p.shape[1])
        diag = diagonal(p)
        if not diag > 0:
            raise InputError(f"all {len(p)} `points` are the same point; nothing to fit")
        if offset is None:
            offset = DEFAULT_OFFSET * diag
        offset = float(offset)
        if not (np.isfinite(offset) and offset > 0):
            raise InputError(f"`offset` must be a positive distance, got {offset!r}")
        pairs = duplicate_pairs_checked(p, nrm, merge_tol * diag)
        drop = find_duplicates(p, merge_tol * diag, pairs)
        p, nrm = p[~drop], nrm[~drop]
        parts_p, parts_v = [p], [np.zeros(len(p))]
        shrunk = dropped = 0
        tree = patches = None
        if validate:
            from scipy.spatial import cKDTree

            tree = cKDTree(p)
            if between and len(p) > 1:
                patches = _patches(tree, p, nrm)
                # the samples that may face another part within reach: the same for both sides
                facing_todo = _maybe_facing(p, nrm, _FACING_REACH * offset)
        for sign in (1.0, -1.0):
            if validate:
                d = _validated_offsets(p, nrm, offset, sign, tree, patches)
            else:
                d = np.full(len(p), offset)
            keep = np.isfinite(d)
            shrunk += int(np.sum(keep & (d < offset)))
            dropped += int(np.sum(~keep))
            value = d
            if patches is not None:  # exact samples: thin walls and narrow gaps
                facing = _facing_distance(
                    tree, p, nrm, offset, sign, patches[0], patches[2], facing_todo
                )
                value = _facing_values(d, facing, offset)
            parts_p.append(p[keep] + sign * d[keep, None] * nrm[keep])
            parts_v.append(sign * value[keep])
        return cls(
            jnp.asarray(np.concatenate(parts_p)),
            jnp.asarray(np.concatenate(parts_v)),
            n_surface=len(p),
            n_shrunk=shrunk,
            n_dropped=dropped,
            n_merged=int(drop.sum()),
        )

    @classmethod
    def from_mesh(
        cls,
        vertices,
        faces,
        offset: float | None = None,
        *,
        points: int | None = None,
        sampling: str = "faces",
        seed: int = 0,
        validate: bool = True,
    ) -> Constraints:
        """Constraints from a triangle mesh.

        **Arguments:**
        - `vertices` (n, 3), `faces` (m, 3) integer indices.
        - `offset`: d in the mesh's units (default 1% of the diagonal).
        - `points`: how many surface points to use. With `sampling="faces"` (default) that many
          points are drawn uniformly over the area, each with its face's normal (default: as many
          as the mesh has vertices). With `sampling="vertices"` the vertices are used with
          area-weighted vertex normals, subsampled at random to `points` if given.
        - `seed`: for the random sampling.
        """
        p, nrm = mesh_samples(vertices, faces, points=points, sampling=sampling, seed=seed)
        return cls.from_points(p, nrm, offset, validate=validate)

    @classmethod
    def from_polyline(
        cls,
        vertices,
        closed: bool | None = None,
        offset: float | None = None,
        *,
        validate: bool = True,
    ) -> Constraints:
        """Constraints from a 2-D polyline, with normals from its segments.

        **Arguments:**
        - `vertices`: (n, 2).
        - `closed`: whether the last vertex joins the first; default: closed if the first and
          last vertices are equal (the repeated vertex is dropped).
        - `offset`: d in the polyline's units (default 1% of the diagonal).

        A closed polyline's normals point out of the region it encloses; an open polyline's point
        to the right of its walking direction.
        """
        v, nrm = polyline_samples(vertices, closed)
        return cls.from_points(v, nrm, offset, validate=validate)

    def with_volume(self, points, values) -> Constraints:
        """These constraints with volume constraints (`points` (k, d), signed-distance `values`)
        appended (replacing any they had)."""
        keep = self.points.shape[0] - self.n_volume
        return Constraints(
            jnp.concatenate([self.points[:keep], jnp.asarray(points, dtype=float)]),
            jnp.concatenate([self.values[:keep], jnp.asarray(values, dtype=float)]),
            n_surface=self.n_surface,
            n_shrunk=self.n_shrunk,
            n_dropped=self.n_dropped,
            n_merged=self.n_merged,
            n_volume=len(values),
        )

    def without_off_surface(self, drop) -> Constraints:
        """These constraints less the off-surface points where `drop` (a mask over the
        off-surface points, in their order) is True; they count as dropped."""
        drop = np.asarray(drop, dtype=bool)
        lo, hi = self.n_surface, self.points.shape[0] - self.n_volume
        if drop.shape != (hi - lo,):
            raise ValueError(f"`drop` must mask the {hi - lo} off-surface points, got {drop.shape}")
        keep = np.concatenate([np.ones(lo, bool), ~drop, np.ones(self.n_volume, bool)])
        return Constraints(
            self.points[keep],
            self.values[keep],
            n_surface=self.n_surface,
            n_shrunk=self.n_shrunk,
            n_dropped=self.n_dropped + int(drop.sum()),
            n_merged=self.n_merged,
            n_volume=self.n_volume,
        )

    def off_surface(self) -> tuple[np.ndarray, np.ndarray]:
        """The off-surface points and their values (positive outside), as host arrays."""
        lo, hi = self.n_surface, self.points.shape[0] - self.n_volume
        return np.asarray(self.points[lo:hi]), np.asarray(self.values[lo:hi])

    def report(self) -> str:
        """One line that says what the constraints hold."""
        line = f"{self.points.shape[0]:,} constraints ({self.n_surface:,} on the surface)"
        extras = []
        if self.n_volume:
            extras.append(f"{self.n_volume:,} volume constraints")
        if self.n_merged:
            extras.append(f"{self.n_merged} duplicate points merged")
        if self.n_shrunk:
            extras.append(f"{self.n_shrunk} offsets shrunk")
        if self.n_dropped:
            extras.append(f"{self.n_dropped} off-surface points dropped")
        return line + (f"; {', '.join(extras)}" if extras else "")


def mesh_samples(
    vertices, faces, *, points: int | None = None, sampling: str = "faces", seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Surface points and outward normals of a triangle mesh (host), as `Constraints.from_mesh`
    uses them: `points` uniform samples with their faces' normals (`sampling="faces"`; default as
    many as the mesh has vertices), or the vertices with area-weighted normals
    (`sampling="vertices"`, subsampled at random to `points` if given)."""
    v = as_points(vertices, "vertices", (3,))
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise InputError(
            f"`faces` must be a non-empty (m, 3) array of vertex indices, got shape {f.shape}"
        )
    if f.min() < 0 or f.max() >= len(v):
        raise InputError(
            f"`faces` refers to vertex {int(f.max())} but there are only {len(v)} vertices"
        )
    f = f.astype(np.int64)
    if points is not None and int(points) < 1:
        raise InputError(f"`points` must be a positive number of samples, got {points}")
    if sampling == "faces":
        p, nrm = sample_faces(v, f, int(points) if points else len(v), seed)
    elif sampling == "vertices":
        used = np.zeros(len(v), dtype=bool)
        used[f.ravel()] = True
        vn = vertex_normals(v, f)
        used &= np.linalg.norm(vn, axis=1) > 0
        p, nrm = v[used], vn[used]
        if points and int(points) < len(p):
            idx = np.random.default_rng(seed).choice(len(p), int(points), replace=False)
            p, nrm = p[idx], nrm[idx]
    else:
        raise InputError(f"`sampling` must be 'faces' or 'vertices', got {sampling!r}")
    return p, nrm


def polyline_samples(vertices, closed: bool | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The vertices of a 2-D polyline and their normals from its segments (host), as
    `Constraints.from_polyline` uses them (a repeated closing vertex is dropped)."""
    v = as_points(vertices, "vertices", (2,))
    if closed is None:
        closed = len(v) > 2 and bool(np.all(v[0] == v[-1]))
    if closed and len(v) > 1 and np.all(v[0] == v[-1]):
        v = v[:-1]
    if len(v) < (3 if closed else 2):
        raise InputError(
            f"a {'closed' if closed else 'open'} polyline needs at least {3 if closed else 2} distinct vertices, got {len(v)}"
        )
    return v, polyline_normals(v, closed)


def offset_caps(points, normals, limit: float, steps: int = 12) -> np.ndarray:
    """For each surface point, the largest offset in (0, `limit`] that passes the Carr et al.
    (2001) test (the off-surface point's nearest input point is its own origin), found by
    bisection on the host; shape (2, n): outside then inside. NaN where even `limit` / 2**steps
    fails. `surface_constraints` clips the offset to these caps, so that the offset d stays a
    differentiable parameter while no off-surface point crosses another part of the surface."""
    from scipy.spatial import cKDTree

    p = as_points(points, "points")
    nrm = _unit_normals(normals, len(p), p.shape[1])
    tree = cKDTree(p)
    own = np.arange(len(p))
    caps = np.empty((2, len(p)))
    for row, sign in enumerate((1.0, -1.0)):

        def ok(d, sign=sign):
            dist, idx = tree.query(p + sign * d[:, None] * nrm, workers=-1)
            return (idx == own) | (dist >= d * (1 - 1e-9))

        lo = np.zeros(len(p))
        hi = np.full(len(p), float(limit))
        good = ok(hi)
        lo[good] = hi[good]
        for _ in range(steps):
            mid = 0.5 * (lo + hi)
            fine = ok(mid) & ~good
            lo = np.where(fine, mid, lo)
            hi = np.where(fine | good, hi, mid)
        caps[row] = np.where(lo > 0, lo, np.nan)
    return caps


def surface_constraints(points, normals, offset, caps=None) -> Constraints:
    """Differentiable constraints: the surface points (value 0), p + d_i n (value +d_i) and
    p - d_i n (value -d_i), with d_i = min(offset, cap_i) — a JAX function of `points`, `normals`
    and `offset`, so that `fit(surface_constraints(...))` can be differentiated with respect to
    all three (the host `Constraints.from_points` cannot: its validation is a discrete loop).

    **Arguments:**
    - `points`, `normals`: (n, d) surface points and outward normals (normalised here).
    - `offset`: d, a scalar in the points' units (may be traced).
    - `caps`: (2, n) per-point largest offsets from `offset_caps` (computed on the host, held
      fixed); points with a NaN cap get no off-surface point on that side. None: no clipping.

    **Returns:** `Constraints` (n surface points first, then outside, then inside).
    """
    p = jnp.asarray(points, dtype=float)
    nrm = jnp.asarray(normals, dtype=float)
    nrm = nrm / jnp.linalg.norm(nrm, axis=1, keepdims=True)
    d = jnp.asarray(offset, dtype=float)
    parts_p, parts_v = [p], [jnp.zeros(p.shape[0], dtype=p.dtype)]
    for row, sign in enumerate((1.0, -1.0)):
        if caps is None:
            keep = np.ones(p.shape[0], dtype=bool)
            di = jnp.broadcast_to(d, (p.shape[0],))
        else:
            cap = np.asarray(caps)[row]
            keep = np.isfinite(cap)
            di = jnp.minimum(d, jnp.asarray(cap[keep]))
        if caps is None:
            pk, nk = p, nrm
        else:
            pk, nk = p[keep], nrm[keep]
        parts_p.append(pk + sign * di[:, None] * nk)
        parts_v.append(sign * di)
    return Constraints(
        jnp.concatenate(parts_p),
        jnp.concatenate(parts_v),
        n_surface=int(p.shape[0]),
        n_dropped=2 * int(p.shape[0]) - (len(parts_v[1]) + len(parts_v[2])),
    )


def progress_bar(total: int, desc: str, unit: str, show: bool | None):
    """A tqdm bar on stderr, the one convention of the package's long loops: shown when `show`
    is True, hidden when False, and by default (None) shown only when stderr is a terminal.
    Callers with a `verbose` flag pass `True if verbose else None`."""
    from tqdm import tqdm

    disable = (not sys.stderr.isatty()) if show is None else not show
    return tqdm(total=total, desc=desc, unit=unit, disable=disable, file=sys.stderr, leave=False)
