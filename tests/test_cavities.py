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
    wall_cavities,
    with_cavities,
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
