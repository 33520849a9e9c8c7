"""Saving and loading models: a versioned `.npz` of plain arrays, read with `allow_pickle=False`."""

from __future__ import annotations

import os

import jax.numpy as jnp
import numpy as np

from ._errors import InputError
from ._model import RBFModel, n_poly
from ._partition import PartitionModel
from ._reconstruct import Fitted
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


def save(
    model: RBFModel | PartitionModel,
    path,
    *,
    samples=None,
    normals=None,
    walls=None,
    shells=None,
) -> None:
    """Write `model` to `path` (`.npz`), atomically: an existing file is replaced only once the new
    one is complete.

    With the fit's surface `samples` (and their `normals`, the `walls` it left out and the
    open `shells` meshed as slabs, as `fit_surface_samples` returns them), the file also holds
    those (`samples.points`, `samples.normals`, `walls.points`, `walls.normals`,
    `shells.points`, `shells.normals`), so that `load_fit` gives back what
    `jaxrbf mesh` needs to mesh the model as `jaxrbf reconstruct` would: the grid that follows
    the samples' spacing, the pruning, the cavities and the output check.

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
    arrays.update(_sample_arrays(model.dim, samples, normals, walls, shells))
    with atomic_output(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)


def _points_array(a, dim: int, what: str) -> np.ndarray:
    """`a` as a finite (n, dim) float64 array, else an `InputError` naming `what`."""
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != dim:
        raise InputError(f"save(): `{what}` must have shape (n, {dim}), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"save(): `{what}` has NaN or infinite values")
    return a


def _sample_arrays(dim: int, samples, normals, walls, shells=None) -> dict[str, np.ndarray]:
    """The optional sample fields of `save`, checked."""
    out = {}
    if samples is None:
        if normals is not None or walls is not None or shells is not None:
            raise InputError(
                "save(): `normals`, `walls` and `shells` are the samples'; pass `samples` too"
            )
        return out
    out["samples.points"] = _points_array(samples, dim, "samples")
    if normals is not None:
        out["samples.normals"] = _points_array(normals, dim, "normals")
        if len(out["samples.normals"]) != len(out["samples.points"]):
            raise InputError("save(): `normals` must have one row per sample")
    for name, pair in (("walls", walls), ("shells", shells)):
        if pair is None:
            continue
        wp, wn = (_points_array(w, dim, f"{name}[{i}]") for i, w in enumerate(pair))
        if len(wp) != len(wn):
            raise InputError(f"save(): `{name}` must be (points, normals) of the same length")
        out[f"{name}.points"], out[f"{name}.normals"] = wp, wn
    return out


class _Fields:
    """The arrays of a model file, read through one validator: every field's presence, dtype,
    shape, finiteness and range is checked before it is used, and a failure names the file and
    the field ("a damaged jaxrbf model")."""

    def __init__(self, data: dict[str, np.ndarray], path: str):
        self.data, self.path = data, path

    def __contains__(self, key: str) -> bool:
        return key in self.data

    def damaged(self, what: str) -> InputError:
        return InputError(
            f"'{self.path}' is a damaged jaxrbf model: {what}; save the model again with "
            "`jaxrbf fit`"
        )

    def _get(self, key: str, shape) -> np.ndarray:
        if key not in self.data:
            raise self.damaged(f"field `{key}` is missing")
        a = self.data[key]
        if shape is not None:
            want = tuple(shape)
            ok = a.ndim == len(want) and all(
                w is None or w == s for w, s in zip(want, a.shape, strict=True)
            )
            if not ok:
                text = "(" + ", ".join("n" if w is None else str(w) for w in want)
                text += ",)" if len(want) == 1 else ")"
                raise self.damaged(
                    f"inconsistent array shapes: field `{key}` has shape {a.shape}, expected {text}"
                )
        return a

    def text(self, key: str, default: str | None = None) -> str:
        """A scalar text field."""
        if default is not None and key not in self.data:
            return default
        a = self._get(key, ())
        if a.dtype.kind not in "US":
            raise self.damaged(f"field `{key}` holds {a.dtype} values, expected text")
        value = a.item()
        return value.decode("utf-8", "replace") if isinstance(value, bytes) else value

    def integer(self, key: str, lo: int, hi: int, shape=()) -> np.ndarray:
        """An integer field (scalar by default) with every value in [lo, hi]."""
        a = self._get(key, shape)
        if a.dtype.kind not in "iu":
            raise self.damaged(f"field `{key}` holds {a.dtype} values, expected whole numbers")
        if a.size and (a.min() < lo or a.max() > hi):
            bad = a.min() if a.min() < lo else a.max()
            raise self.damaged(f"field `{key}` holds {bad}, outside [{lo}, {hi}]")
        return a.astype(np.int64)

    def real(self, key: str, shape=(), finite: bool = True, positive: bool = False) -> np.ndarray:
        """A real field as float64: finite (unless `finite` is False) and, if `positive`,
        greater than 0."""
        a = self._get(key, shape)
        if a.dtype.kind not in "iuf":
            raise self.damaged(f"field `{key}` holds {a.dtype} values, expected real numbers")
        a = a.astype(np.float64)
        if finite and not np.all(np.isfinite(a)):
            raise self.damaged(f"field `{key}` has NaN or infinite values")
        if positive and not np.all(a > 0):
            raise self.damaged(f"field `{key}` must be positive, got {a.min():.6g}")
        return a


def _kernel_from(f: _Fields, pre: str):
    name = f.text(pre + "kernel")
    if name not in KERNELS:
        raise f.damaged(
            f"field `{pre}kernel` names an unknown kernel {name!r} (known: {', '.join(KERNELS)})"
        )
    cls = KERNELS[name]
    if not cls.has_radius:
        f.real(pre + "radius", finite=False)
        return cls()
    return cls(float(f.real(pre + "radius", positive=True)))


def _rbf_from(f: _Fields, pre: str = "") -> RBFModel:
    kernel = _kernel_from(f, pre)
    degree = int(f.integer(pre + "degree", -1, 1))
    c = f.real(pre + "centres", (None, None))
    n, d = c.shape
    if n == 0 or not 1 <= d <= 32:
        raise f.damaged(f"field `{pre}centres` has shape {c.shape}")
    w = f.real(pre + "weights", (n,))
    a = f.real(pre + "coeffs", (n_poly(degree, d),))
    shift = f.real(pre + "shift", (d,))
    scale = f.real(pre + "scale", positive=True)
    residual = f.real(pre + "residual", finite=False)
    background = None
    if pre + "bg.kernel" in f:
        if pre:
            raise f.damaged(f"a background `{pre}bg.` of a background (save writes one level)")
        background = _rbf_from(f, pre + "bg.")
        if background.dim != d:
            raise f.damaged(f"its background is {background.dim}-D but the model is {d}-D")
    return RBFModel(
        centres=jnp.asarray(c),
        weights=jnp.asarray(w),
        coeffs=jnp.asarray(a),
        kernel=kernel,
        shift=jnp.asarray(shift),
        scale=jnp.asarray(scale),
        residual=jnp.asarray(residual),
        degree=degree,
        background=background,
    )


#: At most this many cells in a partition level's grid (its `cell_row` table is read in full).
_MAX_CELLS = 2**31


def _partition_from(f: _Fields) -> PartitionModel:
    model = _rbf_from(f, "base.")
    d = model.dim
    shift = f.real("shift", (d,))
    scale = f.real("scale", positive=True)
    residual = f.real("residual", finite=False)
    levels = int(f.integer("levels", 1, 64))
    for level in range(levels - 1, -1, -1):
        pre = f"level{level}."
        degree = int(f.integer(pre + "degree", -1, 1))
        dims = f.integer(pre + "grid_dims", 1, _MAX_CELLS, (d,))
        cells = int(np.prod(dims))
        if cells > _MAX_CELLS:
            raise f.damaged(f"field `{pre}grid_dims` {tuple(dims)} makes {cells:,} cells")
        origin = f.real(pre + "patch_origin", (None, d))
        p = origin.shape[0]
        radius = f.real(pre + "patch_radius", (p,), positive=True)
        centres = f.real(pre + "patch_centres", (p, None, d))
        m = centres.shape[1]
        weights = f.real(pre + "patch_weights", (p, m))
        coeffs = f.real(pre + "patch_coeffs", (p, n_poly(degree, d)))
        table = f.integer(pre + "patch_table", 0, max(p - 1, 0), (None, None))
        cell_row = f.integer(pre + "patch_cell_row", 0, max(len(table) - 1, 0), (cells,))
        if p == 0 or len(table) == 0:
            raise f.damaged(f"level {level} has no patches")
        grid_lo = f.real(pre + "patch_grid_lo", (d,))
        cell_size = f.real(pre + "cell_size", positive=True)
        model = PartitionModel(
            origin=jnp.asarray(origin),
            radius=jnp.asarray(radius),
            centres=jnp.asarray(centres),
            weights=jnp.asarray(weights),
            coeffs=jnp.asarray(coeffs),
            cell_row=jnp.asarray(cell_row, dtype=jnp.int32),
            table=jnp.asarray(table, dtype=jnp.int32),
            grid_lo=jnp.asarray(grid_lo),
            cell_size=jnp.asarray(cell_size),
            kernel=_kernel_from(f, pre),
            background=model,
            shift=jnp.asarray(shift),
            scale=jnp.asarray(scale),
            residual=jnp.asarray(residual),
            degree=degree,
            grid_dims=tuple(int(k) for k in dims),
        )
    return model


def load(path) -> RBFModel | PartitionModel:
    """Read a model written by `save`, validating every field (presence, dtype, shape,
    finiteness, range) before it is used.

    **Raises:** `InputError` naming the file and the problem, with its own message for a file
    that is no jaxrbf model at all (a foreign file), one written by a newer jaxrbf (a newer
    format) and a damaged one (truncated or corrupt archive, a missing or malformed field).
    """
    return _read(path)[0]


def load_fit(path) -> Fitted:
    """The model of `path` with the samples `save` stored beside it: a `Fitted`
    `(model, points, normals)` with `.walls` and `.shells`, as `fit_surface_samples` returns
    it. `points` and `normals` are None (and the walls and shells empty) for a file saved without samples (by `save`
    without `samples`, or by an earlier jaxrbf); `normals` alone is None when only the
    points were saved. Validated as `load` validates the model."""
    model, f = _read(path)
    dim = model.dim
    points = normals = None
    if "samples.points" in f:
        points = f.real("samples.points", (None, dim))
        if "samples.normals" in f:
            normals = f.real("samples.normals", (len(points), dim))
    pairs = {}
    for name in ("walls", "shells"):
        pairs[name] = (np.zeros((0, dim)), np.zeros((0, dim)))
        if f"{name}.points" in f:
            wp = f.real(f"{name}.points", (None, dim))
            pairs[name] = (wp, f.real(f"{name}.normals", (len(wp), dim)))
    return Fitted(model, points, normals, pairs["walls"], pairs["shells"])


def _read(path) -> tuple[RBFModel | PartitionModel, _Fields]:
    """The model of the file `path` and its validated fields (`load`)."""
    from .io import is_zip_file

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError(f"model file '{path}' does not exist")
    if os.path.getsize(path) == 0:
        raise InputError(
            f"'{path}' is an empty file (0 bytes): the model is truncated or corrupt; save the "
            "model again with `jaxrbf fit`"
        )
    if not is_zip_file(path):
        raise InputError(
            f"'{path}' is not a jaxrbf model: a model is an .npz archive written by `jaxrbf fit` "
            "(this file is not an .npz archive)"
        )
    data = read_npz(path, hint="; save the model again with `jaxrbf fit`")
    f = _Fields(data, path)
    fmt = data.get("format")
    if fmt is None or fmt.dtype.kind not in "US" or FORMAT not in fmt.astype(str):
        names = sorted(data)
        what = f"arrays {', '.join(names[:8])}{', ...' if len(names) > 8 else ''}"
        what = what if names else "no arrays"
        if fmt is not None and fmt.dtype.kind in "US" and fmt.size == 1:
            what = f"format {fmt.item()!r}"
        raise InputError(
            f"'{path}' is not a jaxrbf model (it holds {what}, not format='{FORMAT}'); a model "
            "is written by `jaxrbf fit`"
        )
    if f.text("format") != FORMAT:
        raise f.damaged("field `format` is not the single text 'jaxrbf-model'")
    version = int(f.integer("format_version", 1, np.iinfo(np.int64).max))
    if version > FORMAT_VERSION:
        raise InputError(
            f"'{path}' was written by a newer jaxrbf, in model format {version}, newer than this "
            f"jaxrbf reads ({FORMAT_VERSION}); upgrade jaxrbf to read it"
        )
    kind = f.text("kind", default="rbf")
    if kind == "rbf":
        return _rbf_from(f), f
    if kind == "partition":
        return _partition_from(f), f
    raise f.damaged(f"field `kind` is {kind!r}, expected 'rbf' or 'partition'")
