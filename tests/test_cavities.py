"""Walls inside the solid kept as thin cavities (`jaxrbf._cavities`)."""

import jax.numpy as jnp
import numpy as np
import pytest
from helpers import box, signed_volume

from jaxrbf import is_watertight
from jaxrbf._cavities import (
    DEPTH,
    GRID,
    HALF_WIDTH,
    MIN_SAMPLES,
    REACH,
    SHELL_GRID,
    SHELL_SQUEEZE,
    shell_slabs,
    wall_cavities,
    with_cavities,
    with_shells,
)
from jaxrbf.io import Mesh


def _ball(x):
    """A unit ball's signed distance (negative inside), as a model is called."""
    return jnp.linalg.norm(x, axis=1) - 1.0


def _disc(radius, spacing, z=0.0):
    g = np.arange(-radius, radius + 1e-9, spacing)
    x, y = np.meshgrid(g, g, indexing="ij")
    keep = np.hypot(x, y) <= radius
    p = np.column_stack([x[keep], y[keep], np.full(keep.sum(), z)])
    n = np.tile([0.0, 0.0, 1.0], (len(p), 1))
    n[::2] *= -1  # a wall's samples come from both of its faces
    return p, n


def test_a_wall_inside_the_solid_becomes_a_thin_closed_cavity_round_it():
    spacing = cell = 0.02
    p, n = _disc(0.4, spacing)
    v, f, count = wall_cavities(_ball, p, n, spacing, cell)
    assert count == 1 and len(f) > 100
    assert is_watertight(Mesh(v, f))
    assert signed_volume(Mesh(v, f)) < 0  # its faces face into the cavity, out of the material
    h = GRID * min(spacing, cell)  # the cavities' own grid
    width = HALF_WIDTH * h
    # thin: both faces within a cell of the half-width off the wall's plane
    assert np.all(np.abs(v[:, 2]) < width + h)
    assert np.median(np.abs(v[:, 2])) == pytest.approx(width, abs=0.5 * h)
    # the wall's every sample lies next to the cavity, which reaches just past the wall's rim
    from scipy.spatial import cKDTree

    assert cKDTree(v).query(p)[0].max() < width + h
    assert np.hypot(v[:, 0], v[:, 1]).max() < 0.4 + REACH * spacing + h


def test_a_cavity_stops_short_of_the_outer_surface_and_small_walls_make_none():
    spacing = cell = 0.02
    p, n = _disc(1.3, spacing)  # the wall runs out through the ball's surface
    v, f, count = wall_cavities(_ball, p, n, spacing, cell)
    assert count == 1 and is_watertight(Mesh(v, f))
    # no slot cut into the outer surface: the cavity keeps about its half-width inside it
    assert np.linalg.norm(v, axis=1).max() < 1.0 - (DEPTH - 0.5) * HALF_WIDTH * GRID * spacing
    few, fn = p[: MIN_SAMPLES - 1], n[: MIN_SAMPLES - 1]
    assert wall_cavities(_ball, few, fn, spacing, cell)[2] == 0
    # a "wall" on the outer surface (samples wrongly called buried) leaves no dent
    s = np.random.default_rng(0).normal(size=(4000, 3))
    s /= np.linalg.norm(s, axis=1, keepdims=True)
    assert wall_cavities(_ball, s, s, 0.05, 0.03)[2] == 0
    mesh = Mesh(np.eye(3), np.array([[0, 1, 2]]))
    assert with_cavities(mesh, _ball, s, s, 0.05, 0.03) is mesh


def test_crumbs_a_slab_sheds_are_dropped():
    # two closed pieces: a slab-sized box kept, a crumb far smaller than a wall of MIN_SAMPLES
    # samples dropped
    from jaxrbf._cavities import CRUMB, _without_crumbs

    spacing = 0.01
    side = np.sqrt(CRUMB * MIN_SAMPLES) * spacing  # each face of the slab has the crumb area
    v1, f1 = box([0, 0, 0], [side, side, 0.1 * side])
    v2, f2 = box([1, 1, 1], [spacing, spacing, spacing])
    v, f = np.concatenate([v1, v2]), np.concatenate([f1, f2 + len(v1)])
    kept_v, kept_f = _without_crumbs(v, f, spacing)
    assert len(kept_f) == 12 and np.allclose(kept_v, v1)
    assert len(_without_crumbs(v1, f1, spacing)[1]) == 12  # one piece: kept as it is


def _bent(n, seed=0, curve=0.3):
    """`n` random samples of an open bent sheet z = curve x^2 over the unit square, with its
    upward normals, and the sheet's height function."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-1, 1, (n, 2))
    p = np.column_stack([xy, curve * xy[:, 0] ** 2])
    nrm = np.column_stack([-2 * curve * xy[:, 0], np.zeros(n), np.ones(n)])
    return p, nrm / np.linalg.norm(nrm, axis=1, keepdims=True), lambda x: curve * x[:, 0] ** 2


def test_an_open_shell_becomes_a_thin_closed_slab_that_follows_it():
    p, nrm, height = _bent(4000)
    spacing = 2.0 / np.sqrt(4000)
    cell = 0.03
    v, f, count = shell_slabs(p, nrm, spacing, cell)
    assert count == 1 and len(f) > 1000
    mesh = Mesh(v, f)
    assert is_watertight(mesh)
    assert signed_volume(mesh) > 0  # faces turned out of the slab
    # both faces hug the sheet: within the squeezed half-width of its grid (plus marching's
    # slack), far thinner than a spacing, and smooth: they are not dimpled at the samples
    half = SHELL_SQUEEZE * HALF_WIDTH * SHELL_GRID * min(spacing, cell)
    gap = np.abs(v[:, 2] - height(v))
    assert np.quantile(gap, 0.99) < 2 * half and half < 0.2 * spacing
    # it covers the sheet to its edge and stops within a few spacings past it
    from scipy.spatial import cKDTree

    assert cKDTree(v).query(p)[0].max() < 2 * spacing
    assert np.abs(v[:, :2]).max() < 1 + 3 * spacing
    # a face's normal is the sheet's (up or down), away from the rim
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    fn = np.cross(b - a, c - a)
    area = np.linalg.norm(fn, axis=1)
    centre = (a + b + c) / 3
    inner = np.abs(centre[:, :2]).max(axis=1) < 0.9
    true = np.column_stack([-0.6 * centre[:, 0], np.zeros(len(centre)), np.ones(len(centre))])
    cos = np.abs(np.sum(fn * true, 1)) / area / np.linalg.norm(true, axis=1)
    assert np.average(cos[inner], weights=area[inner]) > 0.995


def test_shell_slabs_join_a_mesh_and_too_few_samples_make_none():
    p, nrm, _ = _bent(2000)
    spacing = 2.0 / np.sqrt(2000)
    base = Mesh(*box([3.0, -0.25, -0.25], 0.5))
    joined = with_shells(base, p, nrm, spacing, 0.05)
    assert len(joined.faces) > len(base.faces) and is_watertight(joined)
    np.testing.assert_array_equal(joined.vertices[: len(base.vertices)], base.vertices)
    # fewer samples than a wall's minimum: nothing added
    assert with_shells(base, p[: MIN_SAMPLES - 1], nrm[: MIN_SAMPLES - 1], spacing, 0.05) is base
