"""jaxrbf: implicit surfaces f(x) = 0 from radial basis functions, in JAX.

Precision: importing jaxrbf turns on JAX's 64-bit mode (`jax_enable_x64`), because the dense
saddle-point solves need float64 (see `jaxrbf._solve`). Set the environment variable
`JAXRBF_NO_X64=1` before importing to keep JAX's default; `fit` then refuses to run.
"""

import os as _os

import jax as _jax

if _os.environ.get("JAXRBF_NO_X64", "") not in ("1", "true", "yes"):
    _jax.config.update("jax_enable_x64", True)

from importlib.metadata import PackageNotFoundError as _PNF
from importlib.metadata import version as _version

from . import csg as csg
from . import features as features
from . import io as io
from . import kernels as kernels
from . import metrics as metrics
from . import objectives as objectives
from . import plot as plot
from ._accounts import AccountReport as AccountReport
from ._accounts import check_output as check_output
from ._background import surface_background as surface_background
from ._clean import OutlierReport as OutlierReport
from ._clean import boundary_loops as boundary_loops
from ._clean import is_watertight as is_watertight
from ._clean import remove_outliers as remove_outliers
from ._constraints import Constraints as Constraints
from ._constraints import offset_caps as offset_caps
from ._constraints import surface_constraints as surface_constraints
from ._denoise import SmoothingReport as SmoothingReport
from ._denoise import choose_smoothing as choose_smoothing
from ._errors import InputError as InputError
from ._errors import JaxRBFError as JaxRBFError
from ._errors import SolveError as SolveError
from ._fit import fit as fit
from ._greedy import GreedyReport as GreedyReport
from ._greedy import greedy_fit as greedy_fit
from ._holes import HoleReport as HoleReport
from ._holes import fill_holes as fill_holes
from ._model import RBFModel as RBFModel
from ._noise import NoiseReport as NoiseReport
from ._noise import estimate_noise as estimate_noise
from ._normals import NormalsReport as NormalsReport
from ._normals import estimate_normals as estimate_normals
from ._partition import PartitionModel as PartitionModel
from ._polygonize import contour as contour
from ._polygonize import polygonize as polygonize
from ._project import project as project
from ._reconstruct import constraints_from as constraints_from
from ._reconstruct import default_resolution as default_resolution
from ._reconstruct import example as example
from ._reconstruct import fit_surface as fit_surface
from ._reconstruct import fit_surface_samples as fit_surface_samples
from ._reconstruct import mesh_fit as mesh_fit
from ._reconstruct import reconstruct as reconstruct
from ._reconstruct import surface_from as surface_from
from ._serialize import load as load
from ._serialize import load_fit as load_fit
from ._serialize import save as save
from ._tune import TuneReport as TuneReport
from ._tune import default_offset as default_offset
from ._tune import default_radius as default_radius
from ._tune import grid_search as grid_search
from ._tune import tune as tune
from ._winding import VolumeConstraints as VolumeConstraints
from ._winding import volume_constraints as volume_constraints
from ._winding import winding_number as winding_number
from .features import Features as Features
from .features import principal_curvatures as principal_curvatures
from .features import sharp_features as sharp_features
from .plot import plot_field as plot_field
from .render import Camera as Camera
from .render import Rendering as Rendering
from .render import mean_curvature as mean_curvature
from .render import mesh_error as mesh_error
from .render import render as render  # the function; the module stays importable as jaxrbf.render
from .render import save_png as save_png

try:
    __version__ = _version("jaxrbf")
except _PNF:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"
