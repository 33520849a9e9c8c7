"""Saving and loading models: a versioned `.npz` of plain arrays, read with `allow_pickle=False`."""

from __future__ import annotations

import os

import jax.numpy as jnp
import numpy as np

from ._errors import InputError
from ._model import RBFModel, n_poly
from ._partition import PartitionModel
from .io import atomic_output, read_npz
from .kernels import KERNELS

FORMAT = "jaxrbf-model"
#: 2 added an `rbf` model's background (`bg.*`); files without one are still written as 1.
FORMAT_VERSION = 2


def _kernel_arrays(kernel, prefix: str) -> dict[str, np.ndarray]:
    return {
        prefix + "kernel": np.array(kernel.name),
        prefix + "radius": np.asarray(getattr(kernel, "radius", np.nan), dtype=np.float64),
    }


def _rbf_arrays(model: RBFModel, prefix: str = "") -> dict[str, np.ndarray]:
    bg = {}
    if model.background is not None:
        if not isinstance(model.background, RBFModel) or model.background.background is not None:
            raise InputError(
                "save() stores a background that is a plain RBFModel (as "
                f"jaxrbf.surface_background builds); got {type(model.background).__name__}"
            )
        bg = _rbf_arrays(model.background, prefix + "bg.")
    return dict(
        _kernel_arrays(model.kernel, prefix),
        **bg,
        **{
            prefix + "degree": np.array(model.degree),
            prefix + "centres": np.asarray(model.centres),
            prefix + "weights": np.asarray(model.weights),
            prefix + "coeffs": np.asarray(model.coeffs),
            prefix + "shift": np.asarray(model.shift),
            prefix + "scale": np.asarray(model.scale),
            prefix + "residual": np.asarray(model.residual),
        },
    )


_PU_FIELDS = ("origin", "radius", "centres", "weights", "coeffs", "cell_row", "table", "grid_lo")


def _partition_arrays(model: PartitionModel) -> dict[str, np.ndarray]:
    arrays: dict[str, np.ndarray] = {}
    level = 0
    while isinstance(model, PartitionModel):
        pre = f"level{level}."
        arrays.update(_kernel_arrays(model.kernel, pre))
        arrays[pre + "degree"] = np.array(model.degree)
        arrays[pre + "cell_size"] = np.asarray(model.cell_size)
        arrays[pre + "grid_dims"] = np.asarray(model.grid_dims, dtype=np.int64)
        for name in _PU_FIELDS:
            arrays[pre + "patch_" + name] = np.asarray(getattr(model, name))
        if level == 0:
            arrays.update(
                shift=np.asarray(model.shift),
                scale=np.asarray(model.scale),
                residual=np.asarray(model.residual),
            )
        model = model.background
        level += 1
    arrays["levels"] = np.array(level)
    arrays.update(_rbf_arrays(model, "base."))
    return arrays


def save(model: RBFModel | PartitionModel, path) -> None:
    """Write `model` to `path` (`.npz`), atomically: an existing file is replaced only once the new
    one is complete.

    The file holds `format`, `format_version`, `kind` (`rbf` or `partition`) and the jaxrbf
    version that wrote it. An `rbf` model adds `kernel`, `radius` (NaN for kernels without one),
    `degree`, `centres`, `weights`, `coeffs`, `shift`, `scale` and `residual`, and its background
    (if any) as another `rbf` model under `bg.` (format version 2). A `partition` model
    adds `shift`, `scale`, `residual`, `levels`, each level's patch arrays (`level{i}.patch_*`,
    `level{i}.kernel`, ...) and the coarsest global fit as an `rbf` model under `base.`.
    """
    from . import __version__

    if not isinstance(model, (RBFModel, PartitionModel)):
        raise InputError(
            f"save() takes an RBFModel or a PartitionModel, got {type(model).__name__}"
        )
    path = os.fspath(path)
    if not path.endswith(".npz"):
        raise InputError(f"a model is saved as .npz; got {path!r}")
    kind = "rbf" if isinstance(model, RBFModel) else "partition"
    body = _rbf_arrays(model) if kind == "rbf" else _partition_arrays(model)
    arrays = dict(
        format=np.array(FORMAT),
        format_version=np.array(FORMAT_VERSION if "bg.kernel" in body else 1),
        kind=np.array(kind),
        jaxrbf_version=np.array(__version__),
    )
    arrays.update(body)
    with atomic_output(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)


def _require(data, path, keys) -> None:
    missing = [k for k in keys if k not in data]
    if missing:
        raise InputError(f"'{path}' is an incomplete jaxrbf model: missing {', '.join(missing)}")


def _finite(data, path, keys) -> None:
    for k in keys:
        if not np.all(np.isfinite(data[k])):
            raise InputError(f"'{path}' has NaN or infinite values in '{k}'")


def _kernel_from(data, path, pre: str):
    name = str(data[pre + "kernel"])
    if name not in KERNELS:
        raise InputError(f"'{path}' names an unknown kernel {name!r}")
    cls = KERNELS[name]
    return cls(float(data[pre + "radius"])) if cls.has_radius else cls()


def _rbf_from(data, path, pre: str = "") -> RBFModel:
    keys = (
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
    _require(data, path, [pre + k for k in keys])
    kernel = _kernel_from(data, path, pre)
    degree = int(data[pre + "degree"])
    c, w, a, shift = (data[pre + k] for k in ("centres", "weights", "coeffs", "shift"))
    ok = (
        degree in (-1, 0, 1)
        and c.ndim == 2
        and c.shape[0] > 0
        and w.shape == (c.shape[0],)
        and shift.shape == (c.shape[1],)
        and a.shape == (n_poly(degree, c.shape[1]),)
        and data[pre + "scale"].shape == ()
    )
    if not ok:
        raise InputError(f"'{path}' has inconsistent array shapes for a jaxrbf model")
    _finite(data, path, [pre + k for k in ("centres", "weights", "coeffs", "shift", "scale")])
    if not float(data[pre + "scale"]) > 0:
        raise InputError(f"'{path}' has a non-positive 'scale'")
    background = None
    if pre + "bg.kernel" in data:
        background = _rbf_from(data, path, pre + "bg.")
        if background.dim != c.shape[1]:
            raise InputError(f"'{path}' has a background of another dimension than its model")
    return RBFModel(
        centres=jnp.asarray(c, dtype=float),
        weights=jnp.asarray(w, dtype=float),
        coeffs=jnp.asarray(a, dtype=float),
        kernel=kernel,
        shift=jnp.asarray(shift, dtype=float),
        scale=jnp.asarray(data[pre + "scale"], dtype=float),
        residual=jnp.asarray(data[pre + "residual"], dtype=float),
        degree=degree,
        background=background,
    )


def _partition_from(data, path) -> PartitionModel:
    _require(data, path, ("levels", "shift", "scale", "residual"))
    model = _rbf_from(data, path, "base.")
    shift, scale = data["shift"], data["scale"]
    _finite(data, path, ("shift", "scale"))
    levels = int(data["levels"])
    if not 1 <= levels <= 64 or shift.shape != (model.dim,) or not float(scale) > 0:
        raise InputError(f"'{path}' has an inconsistent partition-of-unity header")
    for level in range(levels - 1, -1, -1):
        pre = f"level{level}."
        names = [pre + "patch_" + k for k in _PU_FIELDS]
        _require(
            data,
            path,
            names + [pre + k for k in ("kernel", "radius", "degree", "cell_size", "grid_dims")],
        )
        f = {k: data[pre + "patch_" + k] for k in _PU_FIELDS}
        degree = int(data[pre + "degree"])
        dims = tuple(int(d) for d in data[pre + "grid_dims"])
        d = model.dim
        p = f["origin"].shape[0]
        ok = (
            degree in (-1, 0, 1)
            and f["origin"].shape == (p, d)
            and f["radius"].shape == (p,)
            and f["centres"].ndim == 3
            and f["centres"].shape[::2] == (p, d)
            and f["weights"].shape == f["centres"].shape[:2]
            and f["coeffs"].shape == (p, n_poly(degree, d))
            and len(dims) == d
            and min(dims) >= 1
            and f["cell_row"].shape == (int(np.prod(dims)),)
            and f["table"].ndim == 2
            and f["grid_lo"].shape == (d,)
            and np.all((f["table"] >= 0) & (f["table"] < p))
            and np.all((f["cell_row"] >= 0) & (f["cell_row"] < f["table"].shape[0]))
        )
        if not ok:
            raise InputError(f"'{path}' has inconsistent array shapes in level {level}")
        _finite(
            data,
            path,
            [
                pre + "patch_" + k
                for k in ("origin", "radius", "centres", "weights", "coeffs", "grid_lo")
            ]
            + [pre + "cell_size"],
        )
        model = PartitionModel(
            origin=jnp.asarray(f["origin"], dtype=float),
            radius=jnp.asarray(f["radius"], dtype=float),
            centres=jnp.asarray(f["centres"], dtype=float),
            weights=jnp.asarray(f["weights"], dtype=float),
            coeffs=jnp.asarray(f["coeffs"], dtype=float),
            cell_row=jnp.asarray(f["cell_row"], dtype=jnp.int32),
            table=jnp.asarray(f["table"], dtype=jnp.int32),
            grid_lo=jnp.asarray(f["grid_lo"], dtype=float),
            cell_size=jnp.asarray(data[pre + "cell_size"], dtype=float),
            kernel=_kernel_from(data, path, pre),
            background=model,
            shift=jnp.asarray(shift, dtype=float),
            scale=jnp.asarray(scale, dtype=float),
            residual=jnp.asarray(data["residual"], dtype=float),
            degree=degree,
            grid_dims=dims,
        )
    return model


def load(path) -> RBFModel | PartitionModel:
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
    _require(data, path, ("format_version",))
    version = int(data["format_version"])
    if version > FORMAT_VERSION:
        raise InputError(
            f"'{path}' was written in model format {version}, newer than this jaxrbf reads "
            f"({FORMAT_VERSION}); upgrade jaxrbf"
        )
    kind = str(data.get("kind", np.array("rbf")))
    if kind == "rbf":
        return _rbf_from(data, path)
    if kind == "partition":
        return _partition_from(data, path)
    raise InputError(
        f"'{path}' holds an unknown kind of model {kind!r} (expected rbf or partition)"
    )
