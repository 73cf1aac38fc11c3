"""bayescal: Bayesian radiometric calibration of imaging sensors.

Every calibration quantity (per-channel gain, offset, nonlinearity, dark
signal, the integrating sphere's radiance errors) is a random variable; the
models are fitted by NUTS, emcee or a Laplace approximation, beside the
least-squares baseline the calibration literature uses.  See DESIGN.md and
the README.
"""

__version__ = "0.1.0"

from ._config import enable_compilation_cache, enable_float64

enable_float64()
enable_compilation_cache()  # compiled programs persist across processes; BAYESCAL_NO_CACHE=1 turns it off

from .assemble import CalibrationModel, build_model  # noqa: E402
from .batch import FitBatch, fit_many  # noqa: E402
from .calibration import CalibratedRange, Calibration, Setting  # noqa: E402
from .design import Design, Truth, load_design  # noqa: E402
from .diagnostics import Diagnostics  # noqa: E402
from .emva import Steps, load_steps, read_descriptor  # noqa: E402
from .errors import BayescalError, FitFailedError, FitFailedWarning, SpecError, TableError  # noqa: E402
from .fit import BACKENDS, Fit, fit  # noqa: E402
from .images import invert_image, read_image, write_radiance_maps  # noqa: E402
from .inference.lsq import LinearFit, lsq_baseline, lstsq, polyfit  # noqa: E402
from .invert import Inversion, invert, radiance_draws  # noqa: E402
from .nonlinearity import compare_nonlinearity, patent_baseline, simulate_curves  # noqa: E402
from .photon_transfer import Characterization, characterize, standard_method  # noqa: E402
from .plan import Plan, default_window, plan_exposure  # noqa: E402
from .predict import predict  # noqa: E402
from .sbc import SBCResult, run_sbc  # noqa: E402
from .scene import SceneChoice, choose_for_scene  # noqa: E402
from .simulate import Simulation, simulate  # noqa: E402
from .spec import ModelSpec, load_spec  # noqa: E402
from .table import MeasurementTable, load_table  # noqa: E402

__all__ = [
    "__version__",
    "BACKENDS",
    "BayescalError",
    "CalibratedRange",
    "Calibration",
    "CalibrationModel",
    "Characterization",
    "Design",
    "Diagnostics",
    "Fit",
    "FitBatch",
    "FitFailedError",
    "FitFailedWarning",
    "Inversion",
    "LinearFit",
    "MeasurementTable",
    "ModelSpec",
    "Plan",
    "SBCResult",
    "SceneChoice",
    "Setting",
    "Simulation",
    "Steps",
    "SpecError",
    "TableError",
    "Truth",
    "build_model",
    "characterize",
    "choose_for_scene",
    "compare_nonlinearity",
    "default_window",
    "enable_compilation_cache",
    "enable_float64",
    "fit",
    "fit_many",
    "invert",
    "invert_image",
    "load_design",
    "load_spec",
    "load_steps",
    "load_table",
    "lsq_baseline",
    "lstsq",
    "patent_baseline",
    "plan_exposure",
    "polyfit",
    "predict",
    "radiance_draws",
    "read_descriptor",
    "read_image",
    "run_sbc",
    "simulate",
    "simulate_curves",
    "standard_method",
    "write_radiance_maps",
]
