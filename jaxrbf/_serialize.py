"""Saving and loading models: a versioned `.npz` of plain arrays, read with `allow_pickle=False`."""

from __future__ import annotations

import os

import jax.numpy as jnp
import numpy as np

from ._errors import InputError
from ._model import RBFModel, n_poly
from .io import atomic_output, read_npz
from .kernels import KERNELS

FORMAT = "jaxrbf-model"
FORMAT_VERSION = 1


def save(model: RBFModel, path) -> None:
    """Write `model` to `path` (`.npz`), atomically: an existing file is replaced only once the new
    one is complete.

    The file holds `format`, `format_version`, `kind`, `kernel`, `radius` (NaN for kernels without
    one), `degree`, `centres`, `weights`, `coeffs`, `shift`, `scale`, `residual` and the jaxrbf
    version that wrote it.
    """
    from . import __version__

    if not isinstance(model, RBFModel):
        raise InputError(f"save() takes an RBFModel, got {type(model).__name__}")
    path = os.fspath(path)
    if not path.endswith(".npz"):
        raise InputError(f"a model is saved as .npz; got {path!r}")
    radius = getattr(model.kernel, "radius", np.nan)
    arrays = dict(
        format=np.array(FORMAT),
        format_version=np.array(FORMAT_VERSION),
        kind=np.array("rbf"),
        jaxrbf_version=np.array(__version__),
        kernel=np.array(model.kernel.name),
        radius=np.asarray(radius, dtype=np.float64),
        degree=np.array(model.degree),
        centres=np.asarray(model.centres),
        weights=np.asarray(model.weights),
        coeffs=np.asarray(model.coeffs),
        shift=np.asarray(model.shift),
        scale=np.asarray(model.scale),
        residual=np.asarray(model.residual),
    )
    with atomic_output(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)


def load(path) -> RBFModel:
    """Read a model written by `save`, validating every entry.

    **Raises:** `InputError` naming the file and the problem (missing, truncated or corrupt, not a
    jaxrbf model, written by a newer version, inconsistent shapes, NaN).
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError(f"model file '{path}' does not exist")
    data = read_npz(path, hint="; save the model again with `jaxrbf fit`")
    if data.get("format", np.array("")).item() != FORMAT:
        raise InputError(f"'{path}' is not a jaxrbf model (it has no format='{FORMAT}' entry)")
    missing = [
        k
        for k in (
            "format_version",
            "kernel",
            "radius",
            "degree",
            "centres",
            "weights",
            "coeffs",
            "shift",
            "scale",
            "residual",
        )
        if k not in data
    ]
    if missing:
        raise InputError(f"'{path}' is an incomplete jaxrbf model: missing {', '.join(missing)}")
    version = int(data["format_version"])
    if version > FORMAT_VERSION:
        raise InputError(
            f"'{path}' was written in model format {version}, newer than this jaxrbf reads "
            f"({FORMAT_VERSION}); upgrade jaxrbf"
        )
    name = str(data["kernel"])
    if name not in KERNELS:
        raise InputError(f"'{path}' names an unknown kernel {name!r}")
    cls = KERNELS[name]
    degree = int(data["degree"])
    c, w, a, shift = data["centres"], data["weights"], data["coeffs"], data["shift"]
    ok = (
        degree in (-1, 0, 1)
        and c.ndim == 2
        and c.shape[0] > 0
        and w.shape == (c.shape[0],)
        and shift.shape == (c.shape[1],)
        and a.shape == (n_poly(degree, c.shape[1]),)
        and data["scale"].shape == ()
    )
    if not ok:
        raise InputError(f"'{path}' has inconsistent array shapes for a jaxrbf model")
    for k in ("centres", "weights", "coeffs", "shift", "scale"):
        if not np.all(np.isfinite(data[k])):
            raise InputError(f"'{path}' has NaN or infinite values in '{k}'")
    if not float(data["scale"]) > 0:
        raise InputError(f"'{path}' has a non-positive 'scale'")
    kernel = cls(float(data["radius"])) if cls.has_radius else cls()
    return RBFModel(
        centres=jnp.asarray(c, dtype=float),
        weights=jnp.asarray(w, dtype=float),
        coeffs=jnp.asarray(a, dtype=float),
        kernel=kernel,
        shift=jnp.asarray(shift, dtype=float),
        scale=jnp.asarray(data["scale"], dtype=float),
        residual=jnp.asarray(data["residual"], dtype=float),
        degree=degree,
    )
