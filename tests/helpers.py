"""A shape zoo with exact answers, and a finite-difference gradient check."""

import numpy as np


def sphere(n: int = 300, radius: float = 1.0, centre=(0.0, 0.0, 0.0)):
    """Fibonacci points on a sphere with outward normals."""
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = np.pi * (1 + 5**0.5) * i
    nrm = np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)
    return np.asarray(centre) + radius * nrm, nrm


def sphere_sdf(x, radius=1.0, centre=(0.0, 0.0, 0.0)):
    return np.linalg.norm(np.asarray(x) - np.asarray(centre), axis=-1) - radius


def torus(n_major: int = 40, n_minor: int = 16, big: float = 1.0, small: float = 0.35):
    """Points on a torus around the z axis with outward normals."""
    u, v = np.meshgrid(
        np.linspace(0, 2 * np.pi, n_major, endpoint=False),
        np.linspace(0, 2 * np.pi, n_minor, endpoint=False) + 0.1,
        indexing="ij",
    )
    u, v = u.ravel(), v.ravel()
    nrm = np.stack([np.cos(v) * np.cos(u), np.cos(v) * np.sin(u), np.sin(v)], 1)
    ring = np.stack([big * np.cos(u), big * np.sin(u), np.zeros_like(u)], 1)
    return ring + small * nrm, nrm


def torus_sdf(x, big=1.0, small=0.35):
    x = np.asarray(x)
    q = np.linalg.norm(x[..., :2], axis=-1) - big
    return np.hypot(q, x[..., 2]) - small


def ellipse(n: int = 60, a: float = 2.0, b: float = 1.0, closed_repeat: bool = False):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    v = np.stack([a * np.cos(t), b * np.sin(t)], 1)
    return np.vstack([v, v[:1]]) if closed_repeat else v


def franke(x, y):
    """Franke's test function on the unit square."""
    return (
        0.75 * np.exp(-((9 * x - 2) ** 2) / 4 - (9 * y - 2) ** 2 / 4)
        + 0.75 * np.exp(-((9 * x + 1) ** 2) / 49 - (9 * y + 1) / 10)
        + 0.5 * np.exp(-((9 * x - 7) ** 2) / 4 - (9 * y - 3) ** 2 / 4)
        - 0.2 * np.exp(-((9 * x - 4) ** 2) - (9 * y - 7) ** 2)
    )


def fd_gradient(f, x, h=1e-6):
    """Central differences of a scalar function of one point (host floats)."""
    x = np.asarray(x, dtype=float)
    g = np.zeros_like(x)
    for k in range(x.size):
        e = np.zeros_like(x)
        e[k] = h
        g[k] = (float(f(x + e)) - float(f(x - e))) / (2 * h)
    return g


def box(lo, size):
    """A box with corner `lo` and edge lengths `size`: 8 vertices and 12 outward triangles
    (independent of trimesh)."""
    unit = np.array(
        [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]],
        dtype=float,
    )
    faces = np.array(
        [[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
         [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]],
        dtype=np.int64,
    )  # fmt: skip
    return unit * np.asarray(size, dtype=float) + np.asarray(lo, dtype=float), faces


def signed_volume(mesh):
    t = mesh.vertices[mesh.faces]
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6)


def euler(mesh):
    """Euler characteristic V - E + F of a triangle mesh (0 for a torus, 2 for a sphere)."""
    f = mesh.faces
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    return len(mesh.vertices) - len(np.unique(edges, axis=0)) + len(f)
