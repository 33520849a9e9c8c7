"""Hole detection in oriented point clouds, and membrane caps over the holes."""

import numpy as np
import pytest

import jaxrbf
from jaxrbf._holes import boundary_mask


def random_sphere(n, seed=0):
    """Uniform random points on the unit sphere, with outward normals."""
    p = np.random.default_rng(seed).normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    return p, p.copy()


def open_sphere(n=6000, top=0.6, seed=0):
    """The unit sphere without its cap above z = `top`: one round hole of radius
    sqrt(1 - top^2) whose rim lies in the plane z = top."""
    p, nrm = random_sphere(n, seed)
    keep = p[:, 2] < top
    return p[keep], nrm[keep]


def test_a_closed_sphere_has_no_holes():
    p, n = random_sphere(6000)
    cap, cap_n, rep = jaxrbf.fill_holes(p, n)
    assert rep.rims == 0 and rep.capped == 0 and len(cap) == 0 and cap_n.shape == (0, 3)
    assert rep.boundary_points <= 3  # random gaps that wide are rare, and never form a rim
    assert "none found" in rep.summary()


def test_boundary_points_lie_on_the_rim():
    p, n = open_sphere()
    b = boundary_mask(p, n)
    assert b.sum() >= 30
    # flagged points lie within a few spacings of the rim (z = 0.6), but for a rare random gap
    spacing = np.sqrt(4 * np.pi / 6000)
    assert np.mean(0.6 - p[b, 2] < 2.5 * spacing) > 0.95


def _slab(gap_spacings, n=8000, seed=0):
    """Two unit squares `gap_spacings` point spacings apart, randomly sampled, facing away from
    each other and not joined at their edges: a thin plate whose rims are open."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 1, (n, 2))
    spacing = 0.5 / np.sqrt(n / 2)  # the mean nearest-neighbour distance of either face
    z = np.where(np.arange(n) < n // 2, 0.0, gap_spacings * spacing)
    p = np.column_stack([xy, z])
    nrm = np.zeros_like(p)
    nrm[:, 2] = np.where(z > 0, 1.0, -1.0)
    return p, nrm, spacing


@pytest.mark.parametrize("gap", [1.5, 3.0])
def test_a_thin_plate_has_boundary_points_on_its_rims_only(gap):
    # The other face's samples, a spacing or three away, took half of each point's neighbours:
    # the rest left random gaps that read as boundaries all over the faces (359 of 8,000
    # points more than 3 spacings from the rims at 1.5 spacings apart, 155 at 3; now 7 and 4).
    p, n, spacing = _slab(gap)
    b = boundary_mask(p, n)
    edge = np.min(np.column_stack([p[:, :2], 1 - p[:, :2]]), axis=1)
    assert np.sum(b & (edge > 3 * spacing)) <= 20
    assert np.mean(b[edge < 0.3 * spacing]) > 0.8


def test_the_hole_of_an_open_sphere_gets_a_flat_cap_facing_out():
    top = 0.6
    p, n = open_sphere(top=top)
    cap, cap_n, rep = jaxrbf.fill_holes(p, n)
    assert rep.rims == 1 and rep.capped == 1 and rep.added == len(cap) > 20
    assert "1 capped" in rep.summary()
    # the rim is a circle in the plane z = top: its membrane is the flat disc inside it
    assert np.mean(np.abs(cap[:, 2] - top) < 0.03) > 0.95  # rim points lie up to a spacing below
    assert np.all(np.hypot(cap[:, 0], cap[:, 1]) < np.sqrt(1 - top**2) + 0.03)
    np.testing.assert_allclose(np.linalg.norm(cap_n, axis=1), 1.0, atol=1e-9)
    assert np.all(cap_n[:, 2] > 0.9) and np.mean(cap_n[:, 2]) > 0.99  # outward: up, as at the rim


def test_a_flat_sheet_is_not_capped_over_itself():
    g = np.random.default_rng(2).uniform(-1, 1, (4000, 2))
    p = np.c_[g, 0.05 * g[:, 0] ** 2]  # a slightly bent open sheet: its edge is a closed rim
    n = np.c_[-0.1 * g[:, 0], np.zeros(len(g)), np.ones(len(g))]
    cap, _, rep = jaxrbf.fill_holes(p, n)
    assert len(cap) == 0 and rep.capped == 0
    assert rep.rims >= 1 and "would lie along other samples" in rep.summary()


@pytest.mark.slow
def test_fit_surface_caps_the_hole_instead_of_bulging():
    """The fit over the capped samples crosses the sphere's axis near the rim's plane, and so
    does the default fit, whose volume constraints (the winding number) close the hole; with
    neither it continues the sphere's slopes and bulges far above it."""
    top = 0.6
    p, n = open_sphere(1500, top=top)
    axis = np.c_[np.zeros(400), np.zeros(400), np.linspace(0.0, 1.6, 400)]

    def crossing(model):
        f = np.asarray(model(axis))
        return axis[np.argmax(f > 0), 2]  # first point outside, going up the axis

    capped = jaxrbf.fit_surface(p, n, method="dense", fill_holes=True)
    # the volume constraints close it when asked to (by default a piece with an opening of 20%
    # of its area is thickened instead: its samples are all shells)
    closed = jaxrbf.fit_surface(p, n, method="dense", shells=False)
    bare = jaxrbf.fit_surface(p, n, method="dense", volume=False)
    assert abs(crossing(capped) - top) < 0.05  # about a point spacing
    assert abs(crossing(closed) - top) < 0.05
    assert crossing(bare) - top > 0.1
    assert len(jaxrbf.fit_surface_samples(p, n, method="dense").shells[0]) == len(p)


def test_bad_input():
    with pytest.raises(jaxrbf.InputError, match="3-D"):
        jaxrbf.fill_holes(np.zeros((10, 2)), np.ones((10, 2)))
    p, n = open_sphere(500)
    with pytest.raises(jaxrbf.InputError, match="fill_holes"):
        jaxrbf.fit_surface(p, n, fill_holes="yes")


def test_too_few_points_have_no_holes():
    p, n = random_sphere(20)
    cap, _, rep = jaxrbf.fill_holes(p, n)
    assert len(cap) == 0 and rep.rims == 0


@pytest.mark.slow
@pytest.mark.parametrize(
    "extra, method, capped",
    [
        ((), "dense", False),
        # auto leaves holes to the volume constraints' closing samples (it caps a partition
        # only when it is fitted without them: `fit_surface(..., volume=False)`)
        ((), "partition", False),
        (("--holes", "fill"), "partition", True),
        (("--holes", "fill"), "dense", True),
        (("--holes", "keep"), "partition", False),
    ],
)
def test_cli_holes_option(extra, method, capped, tmp_path, capsys):
    from jaxrbf.cli import main

    p, n = open_sphere(1200, top=0.6)
    cloud = tmp_path / "open.ply"
    jaxrbf.io.write_points(cloud, p, n)
    argv = ["fit", str(cloud), "-o", str(tmp_path / "m.npz"), "--method", method, *extra]
    assert main(argv) == 0
    assert ("1 capped" in capsys.readouterr().err) is capped
