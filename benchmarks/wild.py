"""Wild inputs: jaxrbf's default command line against Open3D's screened Poisson, input by input.

What it measures. On every input, jaxrbf runs as a user runs it: `jaxrbf reconstruct IN -o
OUT.ply` in a subprocess, with no options at all (`--jaxrbf-args` appends some; by default none:
the benchmark measures the defaults), its stderr (and stdout) kept in a log file per input, its
wall time measured around the subprocess, so Python start-up, imports and JAX's compilation are
included: it is what the user waits for. A non-zero exit (or a run past `--timeout`, default
1800 s) is a failure, shown with the last line of the log. Open3D's screened Poisson,
`TriangleMesh.create_from_point_cloud_poisson(pcd, depth=9)` with its other parameters at their
defaults and NO density trimming, runs in this process on the same points.

Inputs (files from the shared test data, `../shared/data`; an input whose file is missing is
skipped, and the skipped ones are listed at the end):

1. meshes sampled with their true normals: N points uniform by area on the faces, each with its
   face's normal (`jaxrbf.metrics.sample_surface`, seed `--seed`), written as a binary PLY point
   cloud with nx ny nz. `teapot-10k` (open, non-manifold, several pieces), `suzanne-10k` (open,
   self-touching), `beetle-10k` (a polygon soup of 33 open pieces, whose face normals need not
   agree), `beetle-alt-10k` (one open surface), `bunny-10k` and `bunny-100k`; closed meshes
   the rows above were not developed on: `spot-10k` (low-poly), `cow-10k` (its tail runs into
   the body), `fandisk-10k` (sharp edges) and the sparse `bunny-1k`; at 100k samples also
   `suzanne-100k` and `teapot-100k` (walls inside the solid), `beetle-100k` and
   `beetle-alt-100k` (open pieces that bound no volume). Poisson gets the
   same true normals. The reference is the mesh. `holed-spot-10k`: the closed spot mesh with
   HOLES = 12 round holes cut out (each the faces within 3-6% of the diagonal of a seeded random
   vertex; 19% of the faces go, and one horn tip is cut loose), sampled so; the reference is
   the holed mesh (as for the open meshes: the input is the truth).
2. a virtual range scanner, after Berger et al. 2013 ("A benchmark for surface reconstruction"),
   on the Stanford bunny, the cow and the fandisk (`scan-bunny`, `scan-cow`, `scan-fandisk`),
   and on two meshes the scanner was not developed on, the spot and the open, many-piece
   teapot (`scan-spot`, `scan-teapot`). The
   mesh is moved and scaled to a unit bounding-box diagonal (internally only: the cloud is
   written back in the mesh's own units). SCAN_VIEWS = 8 pinhole cameras look at the box centre
   from SCAN_DISTANCE = 2 diagonals away, in seeded random directions: azimuths stratified (one
   per 45 degree sector, jittered), elevations uniform on the sphere between SCAN_MIN_ELEVATION
   = -20 degrees and the zenith (+y is up), so the underside is seen at best obliquely and some
   regions (the bottom, deep concavities) by no view. Each camera casts a SCAN_PIXELS = 480 x 480
   grid of rays over a SCAN_FOV = 32 degree field of view onto the mesh
   (`open3d.t.geometry.RaycastingScene`); a hit at more than SCAN_MAX_INCIDENCE = 80 degrees
   from the surface normal (grazing) is dropped. Each hit is moved along its ray by Gaussian noise
   of standard deviation SCAN_NOISE = 0.15% of the diagonal x (depth / SCAN_DISTANCE), and each
   view's points get their own small rigid misregistration: a rotation about the centre by an
   angle uniform in SCAN_ROTATION = 0.1-0.2 degrees about a random axis, and a translation of
   SCAN_TRANSLATION = 0.1% of the diagonal in a random direction. The views' points (220k on
   the cow to 340k on the fandisk) are pooled and subsampled uniformly to SCAN_POINTS = 150,000,
   and written WITHOUT normals as a bare `.xyz` file (3 columns). The scanner's progress line
   says how much of the surface no view saw (farther than 1% of the diagonal from every scan
   point; with seed 0 about 0.1% of the cow, 1% of the bunny, 3.5% of the fandisk). jaxrbf gets
   the file as is; Open3D gets the same points and estimates its normals
   (`estimate_normals(KDTreeSearchParamKNN(30))`, `orient_normals_consistent_tangent_plane(30)`,
   timed together with Poisson). The reference is the mesh.
   `--scan-views`, `--scan-points`, `--scan-noise`, `--scan-rotation` and `--scan-shift` run
   the scanner with other settings than the table's (scanners the rows were not developed on;
   the header line and the JSON say which).
   The same scanner with the scanner's own normals (`nscan-cow`, `nscan-spot`: a range scan as
   structured-light and laser scanners deliver it, with normals): each view's normals are
   estimated from that view's noisy points alone (`estimate_normals(KDTreeSearchParamKNN(30))`,
   turned towards that view's camera: `orient_normals_towards_camera_location`), before its
   misregistration, which turns them with the points; written as a PLY with nx ny nz. Both
   methods get the same points and normals.
3. the two real bare clouds `scanned-leg.xyz` (`leg`) and `anchor.xyz` (`anchor`): no normals
   and no reference surface. jaxrbf gets the file; Open3D as in 2. The same clouds with normals
   (`leg-normals`, `anchor-normals`, kind "ncloud": a real scan with its software's normals):
   Open3D's estimate (`estimate_normals(KDTreeSearchParamKNN(30))`,
   `orient_normals_consistent_tangent_plane(30)`) written as a PLY with nx ny nz; both methods
   get the same points and normals.
4. surfaces made here (kind "made", no file needed), of kinds the shared meshes lack, sampled as
   in 1 with their true normals: `cut-sphere-10k`, a sphere with CUT_AWAY = 20% of its area cut
   away (a bowl, a vase, a helmet: one opening a fifth of the surface), and
   `noisy-terrain-20k`, an open height field (TERRAIN_HILLS seeded Gaussian hills and dips on a
   ripple, the kind of an aerial or terrestrial terrain scan) whose samples are moved by Gaussian
   noise of TERRAIN_NOISE = 0.25% of the diagonal (3-D, so jaxrbf sees a noisy cloud);
   `wound-figure-10k`, closed parts that cross and touch, WOUND_PARTS of them with their faces
   wound inside out (as an artist's model has them); `cloth-figure-10k`, a ball with a box on
   it and two cloths running into it, one modelled as two coincident faces wound opposite
   ways, the other as one face; `thin-plate-10k`, a closed plate PLATE (1.4 point spacings
   thick at 10k samples, both faces within every neighbourhood: a card, a blade); `chair-10k`,
   a chair of closed boxes that touch, 4-5 spacings thick (furniture: boards, legs);
   `cup-10k`, a closed cup whose wall and floor are 3.8 spacings thick. The reference is the
   made mesh.
5. `bunny-either-way-10k`: as in 1, with half of the normals flipped at random (normals that
   point either way: an unoriented estimate, a soup wound at random); `bunny-strays-10k`: as
   in 1, with 1% stray points added uniformly in the box grown by 10% a side, with random
   normals. Poisson gets the same points and normals.

Figures, per input and method:
- with a reference (1, 2): wall time (s); Chamfer-L1 (% of the reference's bounding-box
  diagonal) and normal consistency (NC, 1 is best) against the reference; precision (share of
  output-surface samples within 0.5% of the diagonal of the reference's samples) and recall
  (share of reference samples within 0.5% of the output's samples). All from one sampling of
  `--samples` points per surface (default 200,000; `jaxrbf.metrics`, seed `--seed` + 1, the same
  for both methods); sampling alone costs about 0.1% Chamfer at 200k. Also shown, not judged:
  `in->out`, the one-sided mean of (3) on these inputs, where the true surface is known: on
  the noisy virtual scans it tells how much a figure without a reference rewards a surface
  that follows the noise.
- without one (3): the mean and 95th percentile of the distance from the input points to the
  output surface (% of the input's bounding-box diagonal; the surface is sampled at
  ONE_SIDED_SAMPLES = 500,000 points, distances by KD-tree), and the far share: the share of
  the output surface's area (of its samples) farther than 1% of the diagonal from every input
  point, i.e. surface invented where there is no data.
- the true surface (row `truth`, where there is one besides the input: the mesh a virtual scan
  was cast on, the spot before its holes were cut), measured as the outputs are and judged
  against Poisson by the same rule, to tell a criterion that the truth itself would fail: on
  the scans, its in->out is the noise's (the outputs that follow the noise come nearer the
  points); against the holed spot, its closed caps lie farther from the holes' rims than flat
  closings do. Its Chamfer-L1 against itself (a scan's) is the sampling's own floor.
- both: the output mesh's connected components (faces joined by shared vertices), its vertex
  count, and whether it is watertight (`jaxrbf.is_watertight`: every edge shared by exactly two
  consistently oriented faces).

Targets, PASS or FAIL per input, then a summary line:
- with a reference: jaxrbf did not fail, and its Chamfer-L1 <= Poisson's, its NC >= Poisson's
  and its precision at 0.5% >= Poisson's;
- without one: jaxrbf did not fail, and its far share <= Poisson's and its mean distance <=
  Poisson's.
A comparison against a Poisson run that raised counts as met. Open3D's Poisson is not
deterministic (its figures move by a few hundredths of a percent from run to run on the same
points): it runs POISSON_REPEATS = 3 times per input (`--poisson-repeats`), the first is the one
judged against, and the verdicts say where jaxrbf's figure lies within the spread of the runs,
a verdict that is a coin toss. The exit status is 0 whatever the
verdicts (it is a benchmark), unless the script itself fails.

Run from the repository root (Open3D comes with the benchmark extra, `pip install -e .[bench]`):

    python benchmarks/wild.py --list                          # the inputs, and which are present
    python benchmarks/wild.py                                 # everything
    python benchmarks/wild.py --inputs suzanne-10k scan-cow --keep /tmp/wild --json wild.json

`--keep DIR` keeps every input cloud, output mesh and jaxrbf log in DIR (else a temporary folder
is used and removed). jaxrbf runs with this process's environment, unchanged (thread counts,
JAX_PLATFORMS), as a user's shell would start it; other processes on the machine shift the
timings, so the load average at the start is printed with the machine, and so is the
checkout's git commit (jaxrbf is installed editable: its version number alone does not say which
code ran).
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import (  # noqa: E402
    DATA_DIR,
    REPO_ROOT,
    ensure_jaxrbf_importable,
    format_table,
    machine_info,
)

# --- the virtual range scanner (lengths in units of the mesh's bounding-box diagonal) ---------
SCAN_VIEWS = 8
SCAN_DISTANCE = 2.0  # camera distance from the box centre
SCAN_MIN_ELEVATION = -20.0  # degrees; no view from lower down
SCAN_FOV = 32.0  # degrees, horizontal (the images are square)
SCAN_PIXELS = 480  # rays per image side
SCAN_MAX_INCIDENCE = 80.0  # degrees between ray and surface normal; grazing hits beyond are dropped
SCAN_NOISE = 0.0015  # standard deviation along the ray at depth SCAN_DISTANCE (scaled with depth)
SCAN_ROTATION = (0.1, 0.2)  # degrees, per-view misregistration angle range
SCAN_TRANSLATION = 0.001  # per-view misregistration shift
SCAN_POINTS = 150_000  # the pooled hits are subsampled to this many

POISSON_DEPTH = 9
POISSON_REPEATS = 3  # Poisson runs per input: the first is judged against, all give its spread
NORMAL_KNN = 30  # Open3D's normal estimation and orientation, for inputs without normals
THRESHOLD = 0.005  # precision and recall, fraction of the reference's diagonal
FAR = 0.01  # far share, fraction of the input's diagonal
ONE_SIDED_SAMPLES = 500_000
HOLES = 12  # holes cut out of a closed mesh (kind "holed")
CUT_AWAY = 0.2  # the cut sphere's opening, share of its area (kind "made")
TERRAIN_HILLS, TERRAIN_NOISE = 8, 0.0025  # the made terrain's hills and noise (of the diagonal)
PLATE = (1.0, 1.0, 0.02)  # the made thin plate's sides: 10k samples, 1.4 spacings thick
WOUND_PARTS = (1, 3, 5)  # the made wound figure's parts wound inside out (2 limbs and an eye)


@dataclass(frozen=True)
class Input:
    name: str
    kind: str  # "mesh": sampled with true normals; "scan": virtual scanner ("nscan": with the
    # scanner's normals); "cloud": a real scan ("ncloud": with normals estimated and oriented by
    # Open3D, as a scanner's software gives them)
    file: str
    points: int = 0  # surface samples, for kinds "mesh", "holed" and "made"
    noise: float = 0.0  # kind "made": Gaussian noise on the samples, fraction of the diagonal
    flip: float = 0.0  # kind "mesh": share of the samples whose normals are flipped at random
    strays: float = 0.0  # kind "mesh": stray points added in the box (share of the samples)

    def describe(self) -> str:
        if self.kind == "mesh":
            if self.strays:
                return (
                    f"{self.points:,} samples of {self.file} with true normals and "
                    f"{self.strays:.0%} strays in its box (random normals)"
                )
            if self.flip:
                return (
                    f"{self.points:,} samples of {self.file} with true normals, {self.flip:.0%} "
                    "of them flipped at random"
                )
            return f"{self.points:,} samples of {self.file} with true normals"
        if self.kind == "holed":
            return f"{self.points:,} samples of {self.file} with {HOLES} holes cut, true normals"
        if self.kind == "scan":
            return f"virtual range scan of {self.file} ({SCAN_VIEWS} views), no normals"
        if self.kind == "nscan":
            return f"virtual range scan of {self.file} ({SCAN_VIEWS} views), scanner normals"
        if self.kind == "made":
            noise = f", {self.noise:.2%} noise" if self.noise else ""
            return f"{self.points:,} samples of a made {self.file} with true normals{noise}"
        if self.kind == "ncloud":
            return f"{self.file} with Open3D's estimated, oriented normals, no reference"
        return f"{self.file} as is, no normals, no reference"


INPUTS = (
    Input("teapot-10k", "mesh", "teapot.obj", 10_000),
    Input("suzanne-10k", "mesh", "suzanne.obj", 10_000),
    Input("beetle-10k", "mesh", "beetle.obj", 10_000),
    Input("beetle-alt-10k", "mesh", "beetle-alt.obj", 10_000),
    Input("bunny-10k", "mesh", "stanford-bunny.obj", 10_000),
    Input("bunny-100k", "mesh", "stanford-bunny.obj", 100_000),
    Input("holed-spot-10k", "holed", "spot.obj", 10_000),
    Input("spot-10k", "mesh", "spot.obj", 10_000),
    Input("cow-10k", "mesh", "cow.obj", 10_000),
    Input("fandisk-10k", "mesh", "fandisk.obj", 10_000),
    Input("bunny-1k", "mesh", "stanford-bunny.obj", 1_000),
    # pieces that pierce each other, sampled densely: the walls inside the solid (eyeballs sunk
    # in their sockets, a spout inside its body) are a few percent of the true surface
    Input("suzanne-100k", "mesh", "suzanne.obj", 100_000),
    Input("teapot-100k", "mesh", "teapot.obj", 100_000),
    # open pieces that bound no volume (a car body without underside or glass), sampled densely
    Input("beetle-100k", "mesh", "beetle.obj", 100_000),
    Input("beetle-alt-100k", "mesh", "beetle-alt.obj", 100_000),
    Input("scan-bunny", "scan", "stanford-bunny.obj"),
    Input("scan-cow", "scan", "cow.obj"),
    Input("scan-fandisk", "scan", "fandisk.obj"),
    Input("scan-spot", "scan", "spot.obj"),
    Input("scan-teapot", "scan", "teapot.obj"),
    Input("nscan-cow", "nscan", "cow.obj"),
    Input("nscan-spot", "nscan", "spot.obj"),
    Input("leg", "cloud", "scanned-leg.xyz"),
    Input("anchor", "cloud", "anchor.xyz"),
    Input("leg-normals", "ncloud", "scanned-leg.xyz"),
    Input("anchor-normals", "ncloud", "anchor.xyz"),
    # kinds the shared meshes lack, made here: one large opening; an open, noisy terrain
    Input("cut-sphere-10k", "made", "cut-sphere", 10_000),
    Input("noisy-terrain-20k", "made", "terrain", 20_000, noise=TERRAIN_NOISE),
    # an artist's habits: parts wound the other way; cloths as two coincident faces wound
    # opposite ways, or one face, running into a closed part
    Input("wound-figure-10k", "made", "wound-figure", 10_000),
    Input("cloth-figure-10k", "made", "cloth-figure", 10_000),
    # a closed part thinner than two point spacings (a card, a blade): both faces within one
    # neighbourhood; and normals that point either way (an unoriented estimate, a sampled soup)
    Input("thin-plate-10k", "made", "thin-plate", 10_000),
    # furniture: closed boards 4-5 spacings thick that touch (a seat, legs, a back)
    Input("chair-10k", "made", "chair", 10_000),
    # a closed thin-walled vessel: its wall 3.8 spacings thick all round
    Input("cup-10k", "made", "cup", 10_000),
    Input("bunny-either-way-10k", "mesh", "stanford-bunny.obj", 10_000, flip=0.5),
    # stray points in a clean cloud with normals (a scanner's flying pixels, kept with normals)
    Input("bunny-strays-10k", "mesh", "stanford-bunny.obj", 10_000, strays=0.01),
)
BY_NAME = {i.name: i for i in INPUTS}


def present(inp: Input) -> bool:
    """Whether the input can run here: made ones always, the others when their file is there."""
    return inp.kind == "made" or (DATA_DIR / inp.file).is_file()


# --- inputs -----------------------------------------------------------------------------------


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def virtual_scan(mesh, seed: int, with_normals: bool = False):
    """A simulated multi-view range scan of `mesh` (see the module docstring for the model).

    Returns (points (n, 3) in the mesh's units, normals or None, per-scan statistics: among
    them `unseen`, the share of the surface (of SCAN_POINTS area-uniform samples) farther than
    FAR from every scan point). The normals (`with_normals`) are each view's, estimated from
    that view's own noisy points, as a scanner's software does from its range image (Open3D's
    `estimate_normals` with NORMAL_KNN neighbours, turned towards that view's camera), then
    misregistered with them."""
    import open3d as o3d
    from scipy.spatial import cKDTree
    from scipy.spatial.transform import Rotation

    from jaxrbf import metrics

    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    centre, diag = 0.5 * (lo + hi), float(np.linalg.norm(hi - lo))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(((mesh.vertices - centre) / diag).astype(np.float32)),
        o3d.core.Tensor(mesh.faces.astype(np.uint32)),
    )
    rng = np.random.default_rng(seed)
    azimuth = (np.arange(SCAN_VIEWS) + rng.random(SCAN_VIEWS)) * (2 * np.pi / SCAN_VIEWS)
    sin_el = rng.uniform(np.sin(np.radians(SCAN_MIN_ELEVATION)), 1.0, SCAN_VIEWS)
    cos_el = np.sqrt(1.0 - sin_el**2)
    eyes = SCAN_DISTANCE * np.stack(
        [cos_el * np.cos(azimuth), sin_el, cos_el * np.sin(azimuth)], axis=1
    )
    cos_max = np.cos(np.radians(SCAN_MAX_INCIDENCE))
    views, view_normals, hits, grazing = [], [], 0, 0
    for eye, s in zip(eyes, sin_el, strict=True):
        up = [0.0, 1.0, 0.0] if abs(s) < 0.99 else [1.0, 0.0, 0.0]
        rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(
            SCAN_FOV,
            o3d.core.Tensor([0.0, 0.0, 0.0], dtype=o3d.core.float32),
            o3d.core.Tensor(eye.astype(np.float32)),
            o3d.core.Tensor(up, dtype=o3d.core.float32),
            SCAN_PIXELS,
            SCAN_PIXELS,
        )
        cast = scene.cast_rays(rays)
        rays = rays.numpy().reshape(-1, 6).astype(np.float64)
        t = cast["t_hit"].numpy().reshape(-1).astype(np.float64)
        hit = np.isfinite(t)
        direction = rays[hit, 3:]
        length = np.linalg.norm(direction, axis=1)
        u = direction / length[:, None]
        normal = cast["primitive_normals"].numpy().reshape(-1, 3)[hit].astype(np.float64)
        steep = np.abs(np.einsum("ij,ij->i", u, _unit(normal))) >= cos_max
        hits += int(hit.sum())
        grazing += int((~steep).sum())
        depth = (t[hit] * length)[steep]
        depth += rng.normal(size=depth.shape) * (SCAN_NOISE * depth / SCAN_DISTANCE)
        p = eye + depth[:, None] * u[steep]
        axis = _unit(rng.normal(size=3))
        angle = np.radians(rng.uniform(*SCAN_ROTATION))
        shift = SCAN_TRANSLATION * _unit(rng.normal(size=3))
        turn = Rotation.from_rotvec(angle * axis)
        views.append(turn.apply(p) + shift)
        if with_normals:  # from this view's points alone, before its misregistration
            pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
            pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(NORMAL_KNN))
            pc.orient_normals_towards_camera_location(eye)
            view_normals.append(turn.apply(np.asarray(pc.normals)))
    pooled = np.concatenate(views)
    est = np.concatenate(view_normals) if with_normals else None
    if len(pooled) > SCAN_POINTS:
        pick = np.sort(rng.choice(len(pooled), SCAN_POINTS, replace=False))
        pooled = pooled[pick]
        est = est[pick] if with_normals else None
    surface, _ = metrics.sample_surface(mesh, SCAN_POINTS, seed=seed + 2)
    gap = cKDTree(pooled).query((surface - centre) / diag, workers=-1)[0]
    stats = dict(
        views=SCAN_VIEWS,
        elevations_deg=np.degrees(np.arcsin(sin_el)).round(1).tolist(),
        azimuths_deg=np.degrees(azimuth).round(1).tolist(),
        hits=hits,
        grazing_dropped=grazing,
        kept=hits - grazing,
        points=len(pooled),
        unseen=float(np.mean(gap > FAR)),
    )
    return pooled * diag + centre, est, stats


def cut_holes(mesh, count: int, seed: int):
    """`mesh` without the faces whose centroids lie within 3-6% of its diagonal (uniform, per
    hole) of each of `count` seeded random vertices."""
    from jaxrbf import io

    rng = np.random.default_rng(seed)
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    diag = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    centroids = v[f].mean(axis=1)
    keep = np.ones(len(f), dtype=bool)
    for c in v[rng.choice(len(v), count, replace=False)]:
        keep &= np.linalg.norm(centroids - c, axis=1) > rng.uniform(0.03, 0.06) * diag
    return io.Mesh(v, f[keep])


def made_mesh(name: str, seed: int):
    """The made surfaces (kind "made"): "cut-sphere", a unit sphere (icosphere, 20,480 faces)
    turned by a seeded rotation, without the faces whose centroids lie in its top CUT_AWAY of
    area; "terrain", a 160 x 160 height field over the unit square with TERRAIN_HILLS seeded
    Gaussian hills and dips (heights -0.12 to 0.2, widths 0.06 to 0.2) on a ripple of 0.02;
    "wound-figure", an ellipsoid body with 4 seeded capsule limbs that cross it and 2 eyes that
    nearly touch it, the parts WOUND_PARTS wound inside out; "cloth-figure", a ball with a box
    on it and two wavy cloths that run into it, one as two coincident faces wound opposite ways,
    the other as one face; "thin-plate", a box PLATE turned by a seeded rotation; "chair", a
    chair of closed boxes that touch (a seat and a back 0.05 thick, four legs 0.06 square, three
    rungs 0.04 square that touch nothing; 1 x 2 x 1 in all: 4-5 point spacings thick at 10k
    samples) turned by a seeded rotation; "cup", one closed surface of revolution (a cup 1 wide
    and 1 high whose wall and floor are 0.05 thick, 3.8 point spacings at 10k samples) turned
    by a seeded rotation."""
    import trimesh

    from jaxrbf import io

    rng = np.random.default_rng(seed + 11)
    if name == "cut-sphere":
        s = trimesh.creation.icosphere(5, 1.0)
        axis = _unit(rng.normal(size=3))
        s.apply_transform(trimesh.transformations.rotation_matrix(rng.uniform(0, np.pi), axis))
        keep = s.triangles_center[:, 2] < 1 - 2 * CUT_AWAY
        return io.Mesh(np.asarray(s.vertices), np.asarray(s.faces)[keep])
    if name == "terrain":
        k = 160
        u, v = np.meshgrid(np.linspace(0, 1, k), np.linspace(0, 1, k), indexing="ij")
        c = rng.uniform(0.1, 0.9, (TERRAIN_HILLS, 2))
        h = rng.uniform(-0.12, 0.2, TERRAIN_HILLS)
        w = rng.uniform(0.06, 0.2, TERRAIN_HILLS)
        z = 0.02 * np.sin(9 * u) * np.cos(7 * v)
        for ci, hi, wi in zip(c, h, w, strict=True):
            z = z + hi * np.exp(-((u - ci[0]) ** 2 + (v - ci[1]) ** 2) / (2 * wi * wi))
        idx = np.arange(k * k).reshape(k, k)
        a, b, cc, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
        faces = np.concatenate(
            [np.stack([a, b, cc], -1).reshape(-1, 3), np.stack([a, cc, d], -1).reshape(-1, 3)]
        )
        return io.Mesh(np.stack([u, v, z], -1).reshape(-1, 3), faces)
    if name == "thin-plate":
        plate = trimesh.creation.box(PLATE)
        turn = trimesh.transformations.rotation_matrix(
            rng.uniform(0, np.pi), _unit(rng.normal(size=3))
        )
        plate.apply_transform(turn)
        return io.Mesh(np.asarray(plate.vertices), np.asarray(plate.faces))
    if name == "wound-figure":
        body = trimesh.creation.icosphere(4, 1.0)
        body.apply_scale([1.0, 0.7, 1.3])
        parts = [body]
        for i in range(4):
            limb = trimesh.creation.capsule(1.2, 0.22, count=[24, 24])
            ang, tilt = rng.uniform(0, 2 * np.pi), rng.uniform(0.3, 1.2)
            turn = trimesh.transformations.rotation_matrix(tilt, [np.cos(ang), np.sin(ang), 0])
            limb.apply_transform(turn)
            limb.apply_translation([0.7 * np.cos(ang), 0.5 * np.sin(ang), -0.6 + 0.4 * (i % 2)])
            parts.append(limb)
        for x in (-0.3, 0.3):  # eyes, nearly touching the body
            eye = trimesh.creation.icosphere(3, 0.15)
            eye.apply_translation([x, -0.75, 0.6])
            parts.append(eye)
        return _joined(parts, wound=WOUND_PARTS)
    if name == "cloth-figure":
        ball = trimesh.creation.icosphere(4, 0.8)
        box = trimesh.creation.box([0.6, 0.6, 0.6])
        box.apply_translation([0, 0, 1.3])
        k = 60
        u, v = np.meshgrid(np.linspace(-1, 1, k), np.linspace(-0.6, 0.6, k), indexing="ij")
        z = 0.2 + 0.1 * np.sin(3 * u) * np.cos(2 * v)
        idx = np.arange(k * k).reshape(k, k)
        a, b, cc, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
        faces = np.concatenate(
            [np.stack([a, b, cc], -1).reshape(-1, 3), np.stack([a, cc, d], -1).reshape(-1, 3)]
        )
        right = np.stack([u + 1.5, v, z], -1).reshape(-1, 3)  # into the ball from +x
        left = np.stack([-u - 1.5, v, z - 0.4], -1).reshape(-1, 3)  # from -x
        cloths = [
            trimesh.Trimesh(right, faces, process=False),
            trimesh.Trimesh(right, faces[:, ::-1], process=False),  # its second face
            trimesh.Trimesh(left, faces[:, ::-1], process=False),  # one face
        ]
        return _joined([ball, box, *cloths])
    if name == "chair":
        box = trimesh.creation.box
        parts = [box([1.0, 0.05, 1.0]).apply_translation([0, 1.0, 0])]
        for x in (-0.45, 0.45):
            for z in (-0.45, 0.45):
                parts.append(box([0.06, 1.0, 0.06]).apply_translation([x, 0.5, z]))
        parts.append(box([1.0, 1.0, 0.05]).apply_translation([0, 1.5, -0.475]))
        for x in (-0.3, 0.0, 0.3):
            parts.append(box([0.04, 0.04, 0.9]).apply_translation([x, 0.3, 0]))
        turn = trimesh.transformations.rotation_matrix(
            rng.uniform(0, np.pi), _unit(rng.normal(size=3))
        )
        for part in parts:
            part.apply_transform(turn)
        return _joined(parts)
    if name == "cup":
        profile = np.array([[0, 0], [0.5, 0], [0.5, 1.0], [0.45, 1.0], [0.45, 0.05], [0, 0.05]])
        cup = trimesh.creation.revolve(profile, sections=96)
        cup.apply_transform(
            trimesh.transformations.rotation_matrix(
                rng.uniform(0, np.pi), _unit(rng.normal(size=3))
            )
        )
        return io.Mesh(np.asarray(cup.vertices), np.asarray(cup.faces))
    raise ValueError(f"no made surface {name!r}")


def _joined(parts, wound=()):
    """One mesh of the trimesh `parts`, those numbered in `wound` with their faces wound the
    other way."""
    from jaxrbf import io

    vs, fs, off = [], [], 0
    for i, part in enumerate(parts):
        f = np.asarray(part.faces)
        fs.append((f[:, ::-1] if i in wound else f) + off)
        vs.append(np.asarray(part.vertices))
        off += len(part.vertices)
    return io.Mesh(np.concatenate(vs), np.concatenate(fs))


def prepare(inp: Input, workdir: Path, seed: int):
    """(file for jaxrbf, points, normals or None, reference mesh or None, true surface or None,
    notes) for `inp`. The true surface is the closed mesh the input was made from where it is
    more than the reference: the scanned mesh of a virtual scan (the reference too), the mesh
    before its holes were cut."""
    from jaxrbf import io, metrics

    path = DATA_DIR / inp.file
    if inp.kind == "cloud":
        return path, io.read_points(path).points, None, None, None, {}
    if inp.kind == "ncloud":
        points = io.read_points(path).points
        normals = open3d_normals(points)
        out = workdir / f"{inp.name}.ply"
        io.write_points(out, points, normals)
        return out, points, normals, None, None, {}
    if inp.kind == "made":
        ref = made_mesh(inp.file, seed)
        points, normals = metrics.sample_surface(ref, inp.points, seed=seed)
        if inp.noise:
            diag = float(np.linalg.norm(np.ptp(points, axis=0)))
            rng = np.random.default_rng(seed + 13)
            points = points + rng.normal(0.0, inp.noise * diag / np.sqrt(3), points.shape)
        out = workdir / f"{inp.name}.ply"
        io.write_points(out, points, normals)
        return out, points, normals, ref, None, {}
    ref = truth = io.read_mesh(path)
    if inp.kind == "holed":
        ref = cut_holes(truth, HOLES, seed + 7)
    if inp.kind in ("mesh", "holed"):
        points, normals = metrics.sample_surface(ref, inp.points, seed=seed)
        if inp.flip:
            turn = np.random.default_rng(seed + 17).random(len(points)) < inp.flip
            normals = np.where(turn[:, None], -normals, normals)
        if inp.strays:
            rng = np.random.default_rng(seed + 19)
            lo, hi = points.min(axis=0), points.max(axis=0)
            k = int(round(inp.strays * len(points)))
            far = rng.uniform(lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo), (k, 3))
            points = np.concatenate([points, far])
            normals = np.concatenate([normals, _unit(rng.normal(size=(k, 3)))])
        out = workdir / f"{inp.name}.ply"
        io.write_points(out, points, normals)
        return out, points, normals, ref, truth if inp.kind == "holed" else None, {}
    points, normals, stats = virtual_scan(ref, seed, with_normals=inp.kind == "nscan")
    out = workdir / f"{inp.name}.{'ply' if normals is not None else 'xyz'}"
    io.write_points(out, points, normals)
    return out, points, normals, ref, truth, dict(scan=stats)


# --- the two methods --------------------------------------------------------------------------


def jaxrbf_command() -> list[str]:
    """The `jaxrbf` console script of this Python's environment (else the one on PATH)."""
    here = Path(sys.executable).with_name("jaxrbf")
    exe = str(here) if here.is_file() else shutil.which("jaxrbf")
    if exe:
        return [exe]
    return [sys.executable, "-c", "import sys; from jaxrbf.cli import main; sys.exit(main())"]


def _last_line(log: Path) -> str:
    """The last non-blank line of `log` (progress bars' carriage returns split lines too)."""
    text = log.read_text(errors="replace").replace("\r", "\n")
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return lines[-1] if lines else "(no output)"


def run_jaxrbf(source: Path, out: Path, log: Path, extra: list[str], timeout: float) -> dict:
    """`jaxrbf reconstruct source -o out [extra]`, timed; its output goes to `log`."""
    import jaxrbf
    from jaxrbf import io

    cmd = [*jaxrbf_command(), "reconstruct", str(source), "-o", str(out), *extra]
    t0 = time.perf_counter()
    with open(log, "w") as fh:
        try:
            proc = subprocess.run(cmd, stdout=fh, stderr=fh, timeout=timeout, check=False)
        except subprocess.TimeoutExpired:
            seconds = time.perf_counter() - t0
            return dict(ok=False, seconds=seconds, error=f"timed out after {timeout:g} s")
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        return dict(ok=False, seconds=seconds, error=f"exit {proc.returncode}: {_last_line(log)}")
    try:
        mesh = io.read_mesh(out)
    except (OSError, jaxrbf.InputError) as exc:
        return dict(ok=False, seconds=seconds, error=f"exit 0 but {out.name} unreadable: {exc}")
    return dict(ok=True, seconds=seconds, mesh=mesh)


def open3d_normals(points: np.ndarray) -> np.ndarray:
    """Open3D's normals of `points`: plane fits of NORMAL_KNN neighbours, oriented consistently
    over their tangent planes (what Poisson gets where an input has none)."""
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(NORMAL_KNN))
    pc.orient_normals_consistent_tangent_plane(NORMAL_KNN)
    return np.asarray(pc.normals, dtype=np.float64)


def run_poisson(points: np.ndarray, normals: np.ndarray | None, out: Path | None) -> dict:
    """Open3D's screened Poisson at depth 9 on `points` (with Open3D's own normals when `normals`
    is None, their estimation timed too); the mesh is also written to `out` (unless None)."""
    import open3d as o3d

    from jaxrbf import io

    t0 = time.perf_counter()
    try:
        if normals is None:
            normals = open3d_normals(points)
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
        pc.normals = o3d.utility.Vector3dVector(normals)
        m, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pc, depth=POISSON_DEPTH)
    except Exception as exc:  # a benchmark row, not a crash
        error = f"{type(exc).__name__}: {exc}"
        return dict(ok=False, seconds=time.perf_counter() - t0, error=error)
    seconds = time.perf_counter() - t0
    mesh = io.Mesh(np.asarray(m.vertices, np.float64), np.asarray(m.triangles, np.int64))
    if out is not None:
        io.write_mesh(out, mesh)
    return dict(ok=True, seconds=seconds, mesh=mesh)


# --- figures ----------------------------------------------------------------------------------


def components(mesh) -> int:
    """Connected components of the faces (joined through shared vertices)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    f = mesh.faces
    used, local = np.unique(f, return_inverse=True)
    local = local.reshape(f.shape)
    edges = np.concatenate([local[:, [0, 1]], local[:, [1, 2]]])
    n = len(used)
    graph = coo_matrix((np.ones(len(edges), np.int8), (edges[:, 0], edges[:, 1])), shape=(n, n))
    return int(connected_components(graph, directed=False)[0])


def against_reference(mesh, ref, n: int, seed: int) -> dict:
    """Chamfer-L1, NC, precision and recall at THRESHOLD, from one sampling of both surfaces."""
    from jaxrbf import metrics

    # evaluate() reports the F-score only; precision and recall come from the same comparison.
    c = metrics._compare(mesh, ref, n, seed)
    return dict(
        chamfer=metrics._chamfer(c),
        nc=metrics._normal_consistency(c),
        precision=float(np.mean(c["d_pr"] < THRESHOLD)),
        recall=float(np.mean(c["d_rp"] < THRESHOLD)),
    )


def against_points(mesh, points: np.ndarray, seed: int) -> dict:
    """Distances from the input points to the surface, and the surface's far share."""
    from scipy.spatial import cKDTree

    from jaxrbf import metrics

    diag = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    samples, _ = metrics.sample_surface(mesh, ONE_SIDED_SAMPLES, seed=seed)
    to_surface = cKDTree(samples).query(points, workers=-1)[0] / diag
    to_points = cKDTree(points).query(samples, workers=-1)[0] / diag
    return dict(
        mean=float(to_surface.mean()),
        p95=float(np.percentile(to_surface, 95)),
        far=float(np.mean(to_points > FAR)),
    )


def figures(run: dict, points: np.ndarray, ref, args) -> dict:
    """The run's timing and error, plus its mesh's figures when it made a (non-empty) mesh."""
    import jaxrbf

    fig = {k: v for k, v in run.items() if k != "mesh"}
    mesh = run.get("mesh")
    if run["ok"] and len(mesh.faces) == 0:
        fig.update(ok=False, error="the output mesh has no faces")
    if not fig["ok"]:
        return fig
    fig.update(
        vertices=len(mesh.vertices),
        faces=len(mesh.faces),
        components=components(mesh),
        watertight=bool(jaxrbf.is_watertight(mesh)),
    )
    try:
        if ref is not None:
            fig.update(against_reference(mesh, ref, args.samples, args.seed + 1))
            # the one-sided figure of the bare clouds, where the true surface is known (shown,
            # not judged): on a noisy scan it rewards a surface that follows the noise
            fig.update(in_mean=against_points(mesh, points, args.seed + 1)["mean"])
        else:
            fig.update(against_points(mesh, points, args.seed + 1))
    except jaxrbf.InputError as exc:  # e.g. a mesh of degenerate faces only
        fig.update(ok=False, error=f"no metrics: {exc}")
    return fig


# --- verdicts ---------------------------------------------------------------------------------

#: (key, label, lower is better, format) of each judged figure.
REFERENCE_CHECKS = (
    ("chamfer", "Chamfer", True, ".4%"),
    ("nc", "NC", False, ".4f"),
    ("precision", "precision", False, ".2%"),
)
ONE_SIDED_CHECKS = (("far", "far share", True, ".2%"), ("mean", "mean distance", True, ".4%"))


def judged(with_ref: bool) -> tuple:
    """The checks an input is judged by: against its reference, or one-sided."""
    return REFERENCE_CHECKS if with_ref else ONE_SIDED_CHECKS


def verdict(entry: dict) -> tuple[bool, list[str]]:
    """(pass, reasons) for one input."""
    j, p = entry["jaxrbf"], entry["poisson"]
    if not j["ok"]:
        return False, [f"jaxrbf failed ({j['error']})"]
    if not p["ok"]:
        return True, [f"Poisson failed ({p['error']})"]
    checks = judged(entry["reference"])
    reasons = []
    for key, label, lower, fmt in checks:
        if (j[key] > p[key]) if lower else (j[key] < p[key]):
            sign = ">" if lower else "<"
            reasons.append(f"{label} {j[key]:{fmt}} {sign} {p[key]:{fmt}}")
    return not reasons, reasons


def spread(runs: list[dict], with_ref: bool) -> dict:
    """{key: [min, max]} of each judged figure over the Poisson `runs` that did not fail."""
    ok = [r for r in runs if r["ok"]]
    checks = judged(with_ref)
    if not ok:
        return {}
    return {key: [min(r[key] for r in ok), max(r[key] for r in ok)] for key, *_ in checks}


def within_spread(entry: dict) -> list[str]:
    """The judged figures of jaxrbf that lie within Poisson's spread over its runs (a verdict on
    them is a coin toss), as labels."""
    j, sp = entry["jaxrbf"], entry.get("poisson_spread") or {}
    checks = judged(entry["reference"])
    if not j["ok"]:
        return []
    return [label for key, label, *_ in checks if key in sp and sp[key][0] <= j[key] <= sp[key][1]]


# --- reporting --------------------------------------------------------------------------------


def _cells(fig: dict, keys: list[tuple[str, str]]) -> list[str]:
    if not fig["ok"]:
        return [f"{fig['seconds']:.1f}", "FAILED"] + [""] * (len(keys) - 1)
    out = [f"{fig['seconds']:.1f}"]
    for key, fmt in keys:
        v = fig[key]
        out.append("yes" if v is True else "no" if v is False else format(v, fmt))
    return out


def tables(entries: list[dict]) -> str:
    ref_keys = [
        ("chamfer", ".4%"),
        ("nc", ".4f"),
        ("precision", ".2%"),
        ("recall", ".2%"),
        ("in_mean", ".4%"),
        ("components", "d"),
        ("vertices", ",d"),
        ("watertight", ""),
    ]
    one_keys = [
        ("mean", ".4%"),
        ("p95", ".4%"),
        ("far", ".2%"),
        ("components", "d"),
        ("vertices", ",d"),
        ("watertight", ""),
    ]
    blocks = []
    for with_ref, keys, heads, title in (
        (
            True,
            ref_keys,
            ["chamfer-L1", "NC", "prec@0.5%", "rec@0.5%", "in->out", "comps", "verts", "tight"],
            "with a reference (distances in % of the reference's diagonal; in->out: the mean "
            "distance of the input points to the output surface, the bare clouds' figure, "
            "not judged here)",
        ),
        (
            False,
            one_keys,
            ["mean", "p95", "far>1%", "comps", "verts", "tight"],
            "without a reference (input points -> output surface, % of the input's diagonal; "
            "far = share of the output surface > 1% from every point)",
        ),
    ):
        rows = []
        for e in (e for e in entries if e["reference"] == with_ref):
            for method in ("jaxrbf", "poisson", "truth"):
                if method not in e:
                    continue
                label = e["name"] if method == "jaxrbf" else ""
                name = {"poisson": f"poisson{POISSON_DEPTH}"}.get(method, method)
                cells = _cells(e[method], keys)
                if method == "truth":
                    cells[0] = "-"
                rows.append([label, f"{e['points']:,}", name, *cells])
        if rows:
            heads_all = ["input", "points", "method", "s", *heads]
            blocks.append(f"{title}:\n{format_table(heads_all, rows)}")
    return "\n\n".join(blocks)


# --- driver -----------------------------------------------------------------------------------


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--inputs",
        nargs="+",
        metavar="NAME",
        choices=list(BY_NAME),
        default=list(BY_NAME),
        help="a subset of the inputs (see --list; default: all)",
    )
    p.add_argument("--list", action="store_true", help="list the inputs and exit")
    p.add_argument("--seed", type=int, default=0, help="sampling and scanner seed (default 0)")
    p.add_argument("--samples", type=int, default=200_000, help="metric samples (default 200k)")
    p.add_argument("--json", type=Path, metavar="PATH", help="also write every figure to PATH")
    p.add_argument("--keep", type=Path, metavar="DIR", help="keep inputs, outputs and logs in DIR")
    p.add_argument(
        "--jaxrbf-args",
        default="",
        metavar='"..."',
        help="extra arguments appended to jaxrbf's command line (default none: the defaults); "
        "one option alone needs the = form: --jaxrbf-args=--project",
    )
    p.add_argument(
        "--timeout", type=float, default=1800.0, help="seconds per jaxrbf run (default 1800)"
    )
    p.add_argument(
        "--poisson-repeats",
        type=int,
        default=POISSON_REPEATS,
        metavar="N",
        help=f"Poisson runs per input; the first is judged against, the others give its spread "
        f"(default {POISSON_REPEATS}; 1: one run)",
    )
    scanner = p.add_argument_group(
        "the virtual scanner (scan and nscan inputs; defaults: the settings of the table)"
    )
    scanner.add_argument("--scan-views", type=int, metavar="N", help=f"views ({SCAN_VIEWS})")
    scanner.add_argument(
        "--scan-points", type=int, metavar="N", help=f"points kept ({SCAN_POINTS:,})"
    )
    scanner.add_argument(
        "--scan-noise",
        type=float,
        metavar="S",
        help=f"noise along the rays, fraction of the diagonal ({SCAN_NOISE})",
    )
    scanner.add_argument(
        "--scan-rotation",
        type=float,
        nargs=2,
        metavar=("MIN", "MAX"),
        help=f"misregistration angle per view, degrees ({SCAN_ROTATION[0]} {SCAN_ROTATION[1]})",
    )
    scanner.add_argument(
        "--scan-shift",
        type=float,
        metavar="S",
        help=f"misregistration shift per view, fraction of the diagonal ({SCAN_TRANSLATION})",
    )
    args = p.parse_args(argv)
    if args.poisson_repeats < 1:
        p.error(f"--poisson-repeats must be at least 1, got {args.poisson_repeats}")
    if args.scan_views is not None and args.scan_views < 1:
        p.error(f"--scan-views must be at least 1, got {args.scan_views}")
    if args.scan_points is not None and args.scan_points < 100:
        p.error(f"--scan-points must be at least 100, got {args.scan_points}")
    for name in ("scan_noise", "scan_shift"):
        if getattr(args, name) is not None and not 0 <= getattr(args, name) < 0.1:
            p.error(f"--{name.replace('_', '-')} must lie in [0, 0.1), got {getattr(args, name)}")
    if args.scan_rotation is not None and not 0 <= args.scan_rotation[0] <= args.scan_rotation[1]:
        p.error(f"--scan-rotation needs 0 <= MIN <= MAX, got {args.scan_rotation}")
    return args


def set_scanner(args) -> dict:
    """Apply the scanner options of `args` to the module's settings; {option: value} of those
    that differ from the table's, for the printed header and the JSON."""
    global SCAN_VIEWS, SCAN_POINTS, SCAN_NOISE, SCAN_ROTATION, SCAN_TRANSLATION
    changed = {}
    if args.scan_views is not None:
        SCAN_VIEWS = changed["views"] = args.scan_views
    if args.scan_points is not None:
        SCAN_POINTS = changed["points"] = args.scan_points
    if args.scan_noise is not None:
        SCAN_NOISE = changed["noise"] = args.scan_noise
    if args.scan_rotation is not None:
        SCAN_ROTATION = changed["rotation_deg"] = tuple(args.scan_rotation)
    if args.scan_shift is not None:
        SCAN_TRANSLATION = changed["shift"] = args.scan_shift
    return changed


def revision() -> str:
    """The checkout's commit, "-dirty" when its tracked files differ: jaxrbf is installed
    editable, so its version number alone does not say which code ran."""
    try:
        cmd = ["git", "-C", str(REPO_ROOT), "describe", "--always", "--dirty"]
        return subprocess.run(cmd, capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def list_inputs() -> None:
    for inp in INPUTS:
        here = "" if present(inp) else "   [missing: not in DATA_DIR]"
        print(f"{inp.name:18s} {inp.describe()}{here}")
    print(f"(data: {DATA_DIR})")


def run_input(inp: Input, workdir: Path, extra: list[str], args) -> dict:
    """Both methods on one input, their figures and the verdict (progress on stderr)."""
    source, points, normals, ref, truth, notes = prepare(inp, workdir, args.seed)
    print(f"{inp.name}: {len(points):,} points ({inp.describe()})", file=sys.stderr, flush=True)
    if "scan" in notes:
        s = notes["scan"]
        print(
            f"  scanner: {s['views']} views at elevations {s['elevations_deg']} deg; "
            f"{s['hits']:,} hits, {s['grazing_dropped']:,} grazing dropped, "
            f"{s['points']:,} kept; {s['unseen']:.2%} of the surface unseen",
            file=sys.stderr,
            flush=True,
        )
    log = workdir / f"{inp.name}.jaxrbf.log"
    j = run_jaxrbf(source, workdir / f"{inp.name}.jaxrbf.ply", log, extra, args.timeout)
    p = run_poisson(points, normals, workdir / f"{inp.name}.poisson{POISSON_DEPTH}.ply")
    # Open3D's Poisson is not deterministic (its threads): further runs on the same points give
    # the spread of its figures, not judged against, to tell a verdict that is a coin toss
    again = [run_poisson(points, normals, None) for _ in range(args.poisson_repeats - 1)]
    entry = dict(
        name=inp.name,
        kind=inp.kind,
        file=inp.file,
        points=len(points),
        reference=ref is not None,
        jaxrbf=figures(j, points, ref, args),
        poisson=figures(p, points, ref, args),
        **notes,
    )
    entry["pass"], entry["reasons"] = verdict(entry)
    runs = [entry["poisson"], *(figures(a, points, ref, args) for a in again)]
    entry["poisson_spread"] = spread(runs, ref is not None)
    if truth is not None:
        # the true surface judged as the outputs are: which of the criteria it would meet
        entry["truth"] = figures(dict(ok=True, seconds=0.0, mesh=truth), points, ref, args)
        entry["truth_reasons"] = verdict(dict(entry, jaxrbf=entry["truth"]))[1]
    for method in ("jaxrbf", "poisson"):
        f = entry[method]
        status = "ok" if f["ok"] else f["error"]
        print(f"  {method}: {f['seconds']:.1f} s, {status}", file=sys.stderr, flush=True)
    return entry


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.list:
        list_inputs()
        return 0
    ensure_jaxrbf_importable()
    try:
        import open3d as o3d
    except Exception as exc:  # ImportError, or OSError for a missing libusb
        sys.exit(f"error: this benchmark needs open3d ({exc}); pip install -e .[bench]")
    import jaxrbf

    extra = shlex.split(args.jaxrbf_args)
    scanner = set_scanner(args)
    machine = machine_info()
    machine["loadavg_at_start"] = [round(x, 2) for x in os.getloadavg()]
    machine["jaxrbf"] = f"{jaxrbf.__version__} (git {revision()})"
    print(
        f"machine: {machine.get('cpu', '?')}, {machine['cpu_count']} CPUs, load "
        f"{machine['loadavg_at_start']}, Python {machine['python']}; jaxrbf {machine['jaxrbf']}, "
        f"open3d {o3d.__version__}",
        flush=True,
    )
    print(
        f"jaxrbf: `{' '.join(['jaxrbf', 'reconstruct', 'IN', '-o', 'OUT.ply', *extra])}`; "
        f"Poisson: depth {POISSON_DEPTH}, no trimming",
        flush=True,
    )
    if scanner:
        print(f"virtual scanner, not the table's: {scanner}", flush=True)

    names = list(dict.fromkeys(args.inputs))
    here = {n: present(BY_NAME[n]) for n in names}
    skipped = [(n, f"{BY_NAME[n].file} missing") for n in names if not here[n]]
    todo = [BY_NAME[n] for n in names if here[n]]
    for name, why in skipped:
        print(f"skipping {name}: {why} (looked in {DATA_DIR})", flush=True)

    if args.keep:
        args.keep.mkdir(parents=True, exist_ok=True)
        workdir, cleanup = args.keep, None
    else:
        cleanup = tempfile.TemporaryDirectory(prefix="wild-")
        workdir = Path(cleanup.name)

    entries = []
    try:
        for inp in todo:
            entries.append(run_input(inp, workdir, extra, args))
    finally:
        if cleanup is not None:
            cleanup.cleanup()

    print()
    print(tables(entries) or "no input ran")
    print("\nverdicts:")
    for e in entries:
        why = f" ({'; '.join(e['reasons'])})" if e["reasons"] else ""
        print(f"  {e['name']}: {'PASS' if e['pass'] else 'FAIL'}{why}")
        sp = e.get("poisson_spread") or {}
        if args.poisson_repeats > 1 and sp:
            checks = judged(e["reference"])
            ranges = ", ".join(
                f"{label} {sp[key][0]:{fmt}}-{sp[key][1]:{fmt}}" for key, label, _, fmt in checks
            )
            tie = ", ".join(within_spread(e)) or "none"
            print(
                f"    Poisson over {args.poisson_repeats} runs: {ranges}; jaxrbf within that "
                f"spread on: {tie}"
            )
        if "truth" in e:
            would = "; ".join(e["truth_reasons"]) or "none"
            print(f"    the true surface judged so: it would fail on {would}", end="")
            if all(e[m].get("in_mean") is not None for m in ("truth", "jaxrbf", "poisson")):
                print(
                    f"; its in->out {e['truth']['in_mean']:.4%} (jaxrbf "
                    f"{e['jaxrbf']['in_mean']:.4%}, Poisson {e['poisson']['in_mean']:.4%})",
                    end="",
                )
            print()
    passed = [e["name"] for e in entries if e["pass"]]
    failed = [e["name"] for e in entries if not e["pass"]]
    print(
        f"summary: {len(passed)}/{len(entries)} inputs PASS"
        + (f"; FAIL: {', '.join(failed)}" if failed else "")
        + (f"; skipped: {', '.join(n for n, _ in skipped)}" if skipped else "; skipped: none")
    )
    if args.keep:
        print(f"inputs, outputs and jaxrbf logs kept in {workdir}")
    if args.json:
        args.json.write_text(
            json.dumps(
                dict(
                    machine=machine,
                    jaxrbf_args=extra,
                    scanner=scanner,
                    samples=args.samples,
                    seed=args.seed,
                    skipped=dict(skipped),
                    inputs=entries,
                ),
                indent=2,
            )
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
