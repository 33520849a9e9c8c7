"""The check that an output mesh (or set of curves) accounts for its input samples."""

import numpy as np
import pytest
import trimesh

from jaxrbf import _accounts as accounts
from jaxrbf._accounts import (
    FAR_SPACINGS,
    MAX_FAR,
    MAX_MISSED,
    MISS_SPACINGS,
    AccountReport,
    check_curves,
    check_output,
)
from jaxrbf._errors import InputError


def _sphere_samples(n=10_000, seed=0, upper_only=False):
    p = np.random.default_rng(seed).normal(size=(n, 3))
    if upper_only:
        p[:, 2] = np.abs(p[:, 2])
    return p / np.linalg.norm(p, axis=1, keepdims=True)


@pytest.fixture(scope="module")
def sphere():
    m = trimesh.creation.icosphere(subdivisions=4)  # 5,120 faces, chord error ~5e-4
    return np.asarray(m.vertices), np.asarray(m.faces)


@pytest.fixture(scope="module")
def samples():
    return _sphere_samples()


def _sheet(size, z, cells=1):
    """A flat square (2 * cells^2 triangles) of side `size` at height z, centred on the z axis."""
    g = np.linspace(-size / 2, size / 2, cells + 1)
    x, y = np.meshgrid(g, g, indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], axis=1)
    i = np.arange(cells)[:, None] * (cells + 1) + np.arange(cells)[None, :]
    i = i.ravel()
    lower = np.stack([i, i + cells + 1, i + 1], 1)
    upper = np.stack([i + 1, i + cells + 1, i + cells + 2], 1)
    f = np.concatenate([lower, upper])
    return v, f


def _join(*meshes):
    vs, fs, off = [], [], 0
    for v, f in meshes:
        vs.append(v)
        fs.append(f + off)
        off += len(v)
    return np.concatenate(vs), np.concatenate(fs)


# --------------------------------------------------------------------------- passing outputs


def test_sphere_accounts_for_its_own_samples(sphere, samples):
    r = check_output(*sphere, samples)
    assert isinstance(r, AccountReport)
    assert r.ok and r.problem is None
    assert r.missed == 0.0 and r.far == 0.0 and r.far_area == 0.0
    assert r.missed_p95 < 0.1  # the samples lie on the surface, up to the chord error
    assert r.far_p95 < 2.5
    assert r.area == pytest.approx(4 * np.pi, rel=0.01)
    assert r.input_area == pytest.approx(r.area, rel=0.01)
    assert r.n_samples == 10_000 and r.n_faces == 5120 and r.measured == 10_000
    # random samples on the unit sphere: median nearest-neighbour distance sqrt(ln 2 / (pi rho))
    assert r.spacing == pytest.approx(np.sqrt(np.log(2) * 4 * np.pi / 10_000 / np.pi), rel=0.05)
    line = r.summary()
    assert line.startswith("output accounts for its input: 0% of the 10,000 samples farther than 4")
    assert "0% of the surface farther than 10 spacings from every sample" in line
    assert "\n" not in line


def test_dome_over_open_hemisphere_passes(sphere):
    """An open hemisphere closed by its base disk: the disk's middle is far from every sample
    (a real share of the area), yet the output is not mostly invented, so it passes."""
    v, f = sphere
    dome = v.copy()
    dome[:, 2] = np.maximum(dome[:, 2], 0.0)  # the lower half flattened onto the disk z = 0
    r = check_output(dome, f, _sphere_samples(upper_only=True))
    assert r.ok, r.summary()
    assert r.missed < 0.001
    assert 0.1 < r.far < MAX_FAR  # the cap is seen, and tolerated
    assert r.area == pytest.approx(3 * np.pi, rel=0.01)


def test_noisy_samples_pass(sphere):
    """Samples with noise of half a spacing still lie within a few spacings of the surface."""
    p = _sphere_samples(seed=3)
    r0 = check_output(*sphere, p)
    noisy = p + np.random.default_rng(4).normal(size=p.shape) * 0.5 * r0.spacing
    r = check_output(*sphere, noisy, spacing=r0.spacing)
    assert r.ok and r.missed < 0.001
    assert 0.3 < r.missed_p95 < 1.5


# --------------------------------------------------------------------------- failing outputs


def test_tiny_mesh_fails_naming_the_missed_share(samples):
    """The reported bug: 8 faces from a 10,000-point input (pruning dropped the surface)."""
    v = 0.05 * np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1.0]])
    v[:, 2] += 1.0  # a small octahedron touching the sphere at its north pole
    f = np.array(
        [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]]
    )
    r = check_output(v, f, samples)
    assert not r.ok
    assert r.missed > 0.99
    assert r.problem.startswith("100% of the 10,000 input samples lie farther than 4 spacings")
    assert "the output lost part of the input" in r.problem
    assert r.summary().startswith("output does NOT account for its input: 100% of the 10,000")


def test_half_sphere_fails_on_missed_share(sphere, samples):
    v, f = sphere
    keep = v[f].mean(axis=1)[:, 2] > 0
    r = check_output(v, f[keep], samples)
    assert not r.ok and r.far < 0.01
    assert 0.45 < r.missed < 0.55
    assert r.problem.startswith(f"{100 * r.missed:.0f}% of the 10,000 input samples")


def test_balloon_sheet_fails_on_far_share(sphere, samples):
    """A sphere plus a big spurious sheet far away: the output is mostly invented surface."""
    r = check_output(*_join(sphere, _sheet(6.0, 5.0)), samples)
    assert not r.ok
    assert r.missed == 0.0
    assert r.far == pytest.approx(36 / (36 + 4 * np.pi), abs=0.01)
    assert r.far_area == pytest.approx(36, rel=0.02)
    assert r.far_ratio == pytest.approx(36 / (4 * np.pi), rel=0.03)
    assert np.isinf(r.far_p95)  # beyond the search radius
    assert "of the output surface's area (36" in r.problem
    assert "times the area near the samples) lies farther than 10 spacings" in r.problem
    assert "mostly invented surface" in r.problem
    assert "lost part of the input" not in r.problem


def test_small_balloon_is_tolerated(sphere, samples):
    """The same sheet at a third of the sphere's area is reported, not failed."""
    r = check_output(*_join(sphere, _sheet(2.0, 5.0)), samples)
    assert r.ok
    assert r.far == pytest.approx(4 / (4 + 4 * np.pi), abs=0.01)
    assert r.far_ratio == pytest.approx(4 / (4 * np.pi), rel=0.03)


def test_empty_mesh_fails(samples):
    for v in (np.zeros((0, 3)), np.ones((5, 3))):
        r = check_output(v, np.zeros((0, 3), dtype=int), samples)
        assert not r.ok and r.missed == 1.0 and r.n_faces == 0
        assert r.problem.startswith(
            "The output has no triangles, so it accounts for none of the 10,000 input samples"
        )
        assert "does NOT" in r.summary()
    assert not check_output([], [], samples).ok


# --------------------------------------------------------------------------- measuring


def test_threshold_is_exact_next_to_big_faces():
    """Two huge triangles (centroids far from the samples): samples 3.9 spacings above the sheet
    are kept, samples 4.1 spacings above are missed, whatever the faces' size."""
    v, f = _sheet(10.0, 0.0)
    g = np.linspace(-4.9, 4.9, 50)
    x, y = np.meshgrid(g, g)
    s = 0.01
    for h, missed in ((3.9, 0.0), (4.1, 1.0)):
        p = np.stack([x.ravel(), y.ravel(), np.full(x.size, h * s)], axis=1)
        r = check_output(v, f, p, spacing=s)
        assert r.missed == missed
        assert r.missed_p95 == pytest.approx(h)  # exact, though no proxy centroid is near


@pytest.mark.parametrize("subdivisions, s", [(2, 0.05), (1, 0.01), (3, 0.002)])
def test_distances_match_brute_force(subdivisions, s):
    """The proxy-and-refine distances: never below the exact point-to-mesh distance, equal to it
    for nearly every point, and the missed decision (within 4 spacings or not) always exact."""
    rng = np.random.default_rng(5)
    m = trimesh.creation.icosphere(subdivisions=subdivisions)
    el = np.asarray(m.vertices)[np.asarray(m.faces)]
    q = rng.normal(size=(250, 3))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= 1 + rng.uniform(-10 * s, 10 * s, size=(250, 1))
    d = accounts._distance_to(q, el, s)
    tri = np.repeat(el[None], len(q), axis=0).reshape(-1, 3, 3)
    pts = np.repeat(q, len(el), axis=0)
    ref = np.linalg.norm(trimesh.triangles.closest_point(tri, pts) - pts, axis=1)
    ref = ref.reshape(len(q), len(el)).min(axis=1)
    assert np.array_equal(d > MISS_SPACINGS * s, ref > MISS_SPACINGS * s)
    fin = np.isfinite(d)
    assert np.all(ref[~fin] > MISS_SPACINGS * s)  # inf: no proxy within the search radius
    assert np.all(d[fin] >= ref[fin] - 1e-12)
    assert np.all(d[fin] <= ref[fin] + 0.5 * s)
    assert np.mean(d[fin] - ref[fin] < 1e-9) > 0.9


def test_spacing_is_the_median_neighbour_distance_and_ignores_duplicates():
    g = np.arange(30) * 0.1
    x, y = np.meshgrid(g, g)
    p = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    v, f = _sheet(2.9, 0.0)
    v[:, :2] += 1.45
    r = check_output(v, f, np.concatenate([p, p[:400]]))
    assert r.spacing == pytest.approx(0.1)
    assert r.ok and r.missed == 0.0 and r.far == 0.0
    assert check_output(v, f, np.repeat(p, 5, axis=0)).spacing == pytest.approx(0.1)


def test_many_samples_are_subsampled(monkeypatch, sphere):
    v, f = sphere
    keep = v[f].mean(axis=1)[:, 2] > 0
    p = _sphere_samples(4000, seed=7)
    full = check_output(v, f[keep], p)
    monkeypatch.setattr(accounts, "_MAX_QUERIES", 1000)
    part = check_output(v, f[keep], p)
    assert full.measured == 4000 and part.measured == 1000 and part.n_samples == 4000
    assert part.missed == pytest.approx(full.missed, abs=0.05)


def test_reports_are_reproducible(sphere, samples):
    assert check_output(*sphere, samples, seed=3) == check_output(*sphere, samples, seed=3)


# --------------------------------------------------------------------------- curves


def _circle(k, closed=True):
    t = np.linspace(0, 2 * np.pi, k + 1 if closed else k)[: k if not closed else None]
    return np.stack([np.cos(t), np.sin(t)], axis=1)


def test_curves_circle_passes_and_losses_fail():
    rng = np.random.default_rng(1)
    t = rng.uniform(0, 2 * np.pi, 2000)
    p = np.stack([np.cos(t), np.sin(t)], axis=1)
    r = check_curves([_circle(400)], p)
    assert r.ok and r.dim == 2 and r.missed == 0.0 and r.far == 0.0
    assert r.area == pytest.approx(2 * np.pi, rel=1e-3)
    assert "of the curves farther than 10 spacings" in r.summary()

    half = _circle(400)[:201]  # the upper half only
    r = check_curves([half], p)
    assert not r.ok and r.missed == pytest.approx(0.5, abs=0.05)

    far = np.array([[5.0, -20.0], [5.0, 20.0]])  # a 40-long stray segment
    r = check_curves([_circle(400), far], p)
    assert not r.ok and r.missed == 0.0
    assert r.far == pytest.approx(40 / (40 + 2 * np.pi), abs=0.01)
    assert "of the output curves' length" in r.problem

    r = check_curves([], p)
    assert not r.ok and r.problem.startswith("The output has no curve segments")


# --------------------------------------------------------------------------- bad input


def test_nan_in_samples_raises(sphere, samples):
    bad = samples.copy()
    bad[17, 1] = np.nan
    with pytest.raises(InputError, match=r"`samples` has 1 row with NaN or infinite values"):
        check_output(*sphere, bad)


@pytest.mark.parametrize(
    "change, match",
    [
        (lambda v, f, p: (v, f, p[:, :2]), r"`samples` must have 3 columns"),
        (lambda v, f, p: (v, f, p[0]), r"`samples` must be a 2-dimensional array"),
        (lambda v, f, p: (v[:, :2], f, p), r"`vertices` must have 3 columns"),
        (lambda v, f, p: (np.where(v > 0.9, np.inf, v), f, p), r"`vertices` has \d+ rows? with"),
        (lambda v, f, p: (v, f[:, :2], p), r"`faces` must have shape \(m, 3\)"),
        (lambda v, f, p: (v, f + 0.5, p), r"`faces` must hold integer vertex indices"),
        (lambda v, f, p: (v, f + len(v), p), r"`faces` refers to vertex indices up to"),
        (lambda v, f, p: (v, f - len(v), p), r"`faces` holds a negative vertex index"),
        (lambda v, f, p: (np.zeros((4, 2)), np.zeros((0, 3), int), p), r"`vertices` must have"),
    ],
)
def test_bad_arrays_raise_naming_the_argument(sphere, samples, change, match):
    with pytest.raises(InputError, match=match):
        check_output(*change(*sphere, samples))


@pytest.mark.parametrize("spacing", [0.0, -1.0, np.nan, np.inf, "wide"])
def test_bad_spacing_raises(sphere, samples, spacing):
    with pytest.raises(InputError, match=r"`spacing` must be a positive"):
        check_output(*sphere, samples, spacing=spacing)


def test_single_point_needs_a_spacing(sphere):
    for p in (np.ones((3, 3)), [[0.0, 0.0, 1.0]]):
        with pytest.raises(InputError, match=r"`samples` holds no two distinct points.*`spacing`"):
            check_output(*sphere, p)
    r = check_output(*sphere, [[0.0, 0.0, 1.0]], spacing=0.01)
    assert r.missed == 0.0 and r.far > 0.99 and not r.ok


def test_bad_curves_raise():
    p = _circle(50)
    with pytest.raises(InputError, match=r"`curves\[1\]` must have 2 columns"):
        check_curves([_circle(10), np.zeros((5, 3))], p)
    with pytest.raises(InputError, match=r"`samples` must have 2 columns"):
        check_curves([_circle(10)], np.zeros((5, 3)))


def test_constants_are_sane():
    assert 1 < MISS_SPACINGS < FAR_SPACINGS
    assert 0 < MAX_MISSED < MAX_FAR < 1
