"""bayescal: Bayesian radiometric calibration of imaging sensors.

Every calibration quantity (per-channel gain, offset, nonlinearity, dark
signal, the integrating sphere's radiance errors) is a random variable; the
models are fitted by NUTS, emcee or a Laplace approximation, beside the
least-squares baseline the calibration literature uses.  See the README and
``docs/``.

The public API is flat and loaded on first use: ``import bayescal`` imports
neither JAX nor arviz and changes no global setting, so ``bayescal --help``
is instant.  The first use of a computing attribute switches JAX to float64
and turns on bayescal's compilation cache (:func:`bayescal.enable_numerics`).
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING, Any

from ._config import enable_compilation_cache, enable_float64, enable_numerics
from ._version import __version__
from .errors import BayescalError, FitFailedError, FitFailedWarning, SpecError, TableError

#: public name -> module that defines it
_LAZY = {
    "CalibrationModel": ".assemble",
    "build_model": ".assemble",
    "FitBatch": ".batch",
    "fit_many": ".batch",
    "CalibratedRange": ".calibration",
    "Calibration": ".calibration",
    "Setting": ".calibration",
    "Design": ".design",
    "Truth": ".design",
    "load_design": ".design",
    "Diagnostics": ".diagnostics",
    "FleetFit": ".fleet.posterior",
    "compare_pooling": ".fleet.posterior",
    "fit_fleet": ".fleet.posterior",
    "fleet_calibration": ".fleet.export",
    "load_fleet_table": ".fleet.units",
    "Steps": ".emva",
    "load_steps": ".emva",
    "read_descriptor": ".emva",
    "BACKENDS": ".fit",
    "Fit": ".fit",
    "fit": ".fit",
    "invert_image": ".images",
    "read_image": ".images",
    "write_radiance_maps": ".images",
    "LinearFit": ".inference.lsq",
    "lsq_baseline": ".inference.lsq",
    "lstsq": ".inference.lsq",
    "polyfit": ".inference.lsq",
    "MapSet": ".maps.apply",
    "apply_maps": ".maps.apply",
    "build_maps": ".maps.build",
    "make_maps": ".maps.store",
    "read_maps": ".maps.store",
    "write_maps": ".maps.store",
    "load_stacks": ".maps.stacks",
    "write_emva_stacks": ".maps.stacks",
    "Inversion": ".invert",
    "invert": ".invert",
    "radiance_draws": ".invert",
    "compare_nonlinearity": ".nonlinearity",
    "patent_baseline": ".nonlinearity",
    "simulate_curves": ".nonlinearity",
    "Characterization": ".photon_transfer",
    "characterize": ".photon_transfer",
    "standard_method": ".photon_transfer",
    "Plan": ".plan",
    "default_window": ".plan",
    "plan_exposure": ".plan",
    "predict": ".predict",
    "SBCResult": ".sbc",
    "run_sbc": ".sbc",
    "SceneChoice": ".scene",
    "choose_for_scene": ".scene",
    "Simulation": ".simulate",
    "simulate": ".simulate",
    "ModelSpec": ".spec",
    "load_spec": ".spec",
    "MeasurementTable": ".table",
    "load_table": ".table",
}

__all__ = sorted(
    [
        "__version__",
        "BayescalError",
        "FitFailedError",
        "FitFailedWarning",
        "SpecError",
        "TableError",
        "enable_compilation_cache",
        "enable_float64",
        "enable_numerics",
        *_LAZY,
    ]
)


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'bayescal' has no attribute '{name}'")
    enable_numerics()
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__


class _Package(types.ModuleType):
    """The package module: a submodule named like a public function (``fit``, ``simulate``,
    ``invert``, ``predict``) must not replace that function when the import system binds it."""

    def __setattr__(self, name: str, value: Any) -> None:
        if name in _LAZY and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package


if TYPE_CHECKING:  # pragma: no cover - static analysers see the eager imports
    from .assemble import CalibrationModel, build_model
    from .batch import FitBatch, fit_many
    from .calibration import CalibratedRange, Calibration, Setting
    from .design import Design, Truth, load_design
    from .diagnostics import Diagnostics
    from .emva import Steps, load_steps, read_descriptor
    from .fit import BACKENDS, Fit, fit
    from .fleet.export import fleet_calibration
    from .fleet.posterior import FleetFit, compare_pooling, fit_fleet
    from .fleet.units import load_fleet_table
    from .images import invert_image, read_image, write_radiance_maps
    from .inference.lsq import LinearFit, lsq_baseline, lstsq, polyfit
    from .invert import Inversion, invert, radiance_draws
    from .maps.apply import MapSet, apply_maps
    from .maps.build import build_maps
    from .maps.stacks import load_stacks, write_emva_stacks
    from .maps.store import make_maps, read_maps, write_maps
    from .nonlinearity import compare_nonlinearity, patent_baseline, simulate_curves
    from .photon_transfer import Characterization, characterize, standard_method
    from .plan import Plan, default_window, plan_exposure
    from .predict import predict
    from .sbc import SBCResult, run_sbc
    from .scene import SceneChoice, choose_for_scene
    from .simulate import Simulation, simulate
    from .spec import ModelSpec, load_spec
    from .table import MeasurementTable, load_table
