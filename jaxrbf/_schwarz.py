"""Overlapping domain decomposition of the centres, for the Schwarz preconditioner of the solvers.

Host-side (numpy + scipy's cKDTree): the index sets are integer constants of the solve, built once
per fit from the normalised centres, so the jit-compiled solve sees fixed shapes.

- **Subdomains**: a k-d split of the centres (halve along the longest side of the bounding box)
  into leaves of at most `leaf` points; each subdomain is its leaf plus the `overlap` nearest
  neighbours of every leaf point, so neighbouring subdomains overlap by a few point spacings.
  They are padded to one common size with a mask.
- **Coarse set**: one centre per cell of a second k-d split into `coarse` cells (the median point of
  each), an even spatial subsample that carries the global, smooth part of the solution that local
  solves cannot see (Beatson, Light & Billings 2000).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

#: Defaults from a sweep on 12,000 constraints from spot (cubic kernel, CG, warm fit times on 2
#: cores): leaf/overlap/coarse 800/20/none 5.1 s, 800/20/1500 4.1 s, 500/20/1500 3.9 s,
#: 400/15/1500 4.4 s, 600/20/2000 4.5 s, 1200/20/1500 5.4 s. Smaller leaves make the local
#: inverses cheaper (cost n m^2) but need more iterations; the coarse set saves about a fifth of them.
LEAF = 500
OVERLAP = 20
COARSE_FRACTION = 1 / 8
#: The coarse solve is one dense (c + k)^2 inverse; beyond this size it would cost more than it saves.
COARSE_MAX = 2000


class Decomposition(NamedTuple):
    idx: np.ndarray  # (s, m) int32 subdomain members, padded with 0
    mask: np.ndarray  # (s, m) bool, False on padding
    coarse: np.ndarray  # (c,) int32, possibly empty

    @property
    def n_subdomains(self) -> int:
        return int(self.idx.shape[0])


def _kd_leaves(x: np.ndarray, idx: np.ndarray, parts: int) -> list[np.ndarray]:
    """Split `idx` into `parts` spatially compact groups of nearly equal size."""
    if parts <= 1 or len(idx) <= 1:
        return [idx]
    ext = np.ptp(x[idx], axis=0)
    left = parts // 2
    cut = round(len(idx) * left / parts)
    if cut <= 0 or cut >= len(idx):
        return [idx]
    # A partial sort is enough: everything left of `cut` is <= everything right of it.
    order = idx[np.argpartition(x[idx, int(np.argmax(ext))], cut)]
    return _kd_leaves(x, order[:cut], left) + _kd_leaves(x, order[cut:], parts - left)


def decompose(
    x: np.ndarray, leaf: int = LEAF, overlap: int = OVERLAP, coarse: int | None = None
) -> Decomposition:
    """Overlapping subdomains and a coarse set for centres `x` (n, d)."""
    x = np.asarray(x, dtype=np.float64)
    n = len(x)
    parts = max(1, -(-n // max(1, leaf)))
    leaves = _kd_leaves(x, np.arange(n), parts)
    if parts == 1:
        subs = [np.arange(n)]
    else:
        k = min(max(1, overlap), n)
        _, nb = cKDTree(x).query(x, k=k)
        nb = nb.reshape(n, -1)
        subs = [np.unique(nb[lf].ravel()) for lf in leaves]
    m = max(len(s) for s in subs)
    idx = np.zeros((len(subs), m), dtype=np.int32)
    mask = np.zeros((len(subs), m), dtype=bool)
    for i, s in enumerate(subs):
        idx[i, : len(s)] = s
        mask[i, : len(s)] = True
    if coarse is None:
        coarse = min(int(COARSE_FRACTION * n), COARSE_MAX)
    if parts == 1 or coarse < 2:
        cidx = np.zeros((0,), dtype=np.int32)
    else:
        cells = _kd_leaves(x, np.arange(n), min(coarse, n))
        cidx = np.sort(np.array([c[len(c) // 2] for c in cells], dtype=np.int32))
    return Decomposition(idx, mask, cidx)
