"""bayescal: Bayesian radiometric calibration of imaging sensors.

Every calibration quantity (per-channel gain, offset, nonlinearity, dark
signal, the integrating sphere's radiance errors) is a random variable; the
models are fitted by NUTS, emcee or a Laplace approximation, beside the
least-squares baseline the calibration literature uses.  See the README and
``docs/``.

The public API is flat and loaded on first use: ``import bayescal`` imports
neither JAX nor arviz and changes no global setting, so ``bayescal --help``
is instant.  Functions that compute run in float64 with bayescal's compilation
cache, and put JAX's settings back when they return (:func:`bayescal.numerics`);
:func:`bayescal.enable_numerics` switches both on for the whole process.
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING, Any

from bayescal._config import enable_compilation_cache, enable_float64, enable_numerics, numerics
from bayescal._version import __version__
from bayescal.errors import BayescalError, FitFailedError, FitFailedWarning, SpecError, TableError

#: public name -> module that defines it
_LAZY = {
    "CalibrationModel": "bayescal.model.assemble",
    "build_model": "bayescal.model.assemble",
    "FitBatch": "bayescal.fitting.batch",
    "fit_many": "bayescal.fitting.batch",
    "CalibratedRange": "bayescal.posterior.calibration",
    "Calibration": "bayescal.posterior.calibration",
    "Setting": "bayescal.model.setting",
    "Design": "bayescal.io.design",
    "CampaignDesign": "bayescal.campaign.design",
    "design": "bayescal.campaign.design",
    "DesignCheck": "bayescal.validation.design",
    "check_design": "bayescal.validation.design",
    "Truth": "bayescal.io.design",
    "load_design": "bayescal.io.design",
    "Diagnostics": "bayescal.inference.diagnostics",
    "FleetFit": "bayescal.fleet.posterior",
    "compare_pooling": "bayescal.fleet.posterior",
    "fit_fleet": "bayescal.fleet.posterior",
    "fleet_calibration": "bayescal.fleet.export",
    "load_fleet_table": "bayescal.fleet.units",
    "Steps": "bayescal.io.emva",
    "load_steps": "bayescal.io.emva",
    "read_descriptor": "bayescal.io.emva",
    "read_groups": "bayescal.io.emva",
    "ImageGroup": "bayescal.io.emva",
    "BACKENDS": "bayescal.fitting.fit",
    "Fit": "bayescal.fitting.result",
    "fit": "bayescal.fitting.fit",
    "Diagnosis": "bayescal.fitting.diagnosis",
    "diagnose": "bayescal.fitting.diagnosis",
    "fit_diagnosed": "bayescal.fitting.diagnosis",
    "invert_image": "bayescal.prediction.images",
    "read_image": "bayescal.prediction.images",
    "write_radiance_maps": "bayescal.prediction.images",
    "LinearFit": "bayescal.inference.lsq",
    "lsq_baseline": "bayescal.inference.lsq",
    "lstsq": "bayescal.inference.lsq",
    "polyfit": "bayescal.inference.lsq",
    "MapSet": "bayescal.maps.apply",
    "apply_maps": "bayescal.maps.apply",
    "build_maps": "bayescal.maps.build",
    "make_maps": "bayescal.maps.store",
    "read_maps": "bayescal.maps.store",
    "write_maps": "bayescal.maps.store",
    "load_stacks": "bayescal.maps.stacks",
    "write_emva_stacks": "bayescal.maps.stacks",
    "Inversion": "bayescal.prediction.invert",
    "invert": "bayescal.prediction.invert",
    "radiance_draws": "bayescal.prediction.invert",
    "compare_nonlinearity": "bayescal.characterization.nonlinearity",
    "patent_baseline": "bayescal.characterization.nonlinearity",
    "simulate_curves": "bayescal.characterization.nonlinearity",
    "Characterization": "bayescal.characterization.emva1288",
    "characterize": "bayescal.characterization.emva1288",
    "standard_method": "bayescal.characterization.emva1288",
    "write_datasheet": "bayescal.characterization.datasheet",
    "write_curves": "bayescal.characterization.datasheet",
    "write_report": "bayescal.report.html",
    "maps_report": "bayescal.maps.report",
    "FleetDesign": "bayescal.validation.fleet",
    "simulate_fleet": "bayescal.validation.fleet",
    "fleet_from_frame": "bayescal.fleet.units",
    "Plan": "bayescal.prediction.plan",
    "default_window": "bayescal.prediction.plan",
    "plan_exposure": "bayescal.prediction.plan",
    "predict": "bayescal.prediction.readings",
    "SBCResult": "bayescal.validation.sbc",
    "run_sbc": "bayescal.validation.sbc",
    "SceneChoice": "bayescal.prediction.scene",
    "choose_for_scene": "bayescal.prediction.scene",
    "Simulation": "bayescal.model.simulate",
    "simulate": "bayescal.model.simulate",
    "ModelSpec": "bayescal.model.spec",
    "Reference": "bayescal.model.spec",
    "load_spec": "bayescal.model.spec",
    "MeasurementTable": "bayescal.io.table",
    "load_table": "bayescal.io.table",
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
        "numerics",
        *_LAZY,
    ]
)


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'bayescal' has no attribute '{name}'")
    value = getattr(importlib.import_module(module), name)
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
    from bayescal.campaign.design import CampaignDesign, design
    from bayescal.characterization.datasheet import write_curves, write_datasheet
    from bayescal.characterization.emva1288 import Characterization, characterize, standard_method
    from bayescal.characterization.nonlinearity import compare_nonlinearity, patent_baseline, simulate_curves
    from bayescal.fitting.batch import FitBatch, fit_many
    from bayescal.fitting.diagnosis import Diagnosis, diagnose, fit_diagnosed
    from bayescal.fitting.fit import BACKENDS, fit
    from bayescal.fitting.result import Fit
    from bayescal.fleet.export import fleet_calibration
    from bayescal.fleet.posterior import FleetFit, compare_pooling, fit_fleet
    from bayescal.fleet.units import fleet_from_frame, load_fleet_table
    from bayescal.inference.diagnostics import Diagnostics
    from bayescal.inference.lsq import LinearFit, lsq_baseline, lstsq, polyfit
    from bayescal.io.design import Design, Truth, load_design
    from bayescal.io.emva import ImageGroup, Steps, load_steps, read_descriptor, read_groups
    from bayescal.io.table import MeasurementTable, load_table
    from bayescal.maps.apply import MapSet, apply_maps
    from bayescal.maps.build import build_maps
    from bayescal.maps.report import maps_report
    from bayescal.maps.stacks import load_stacks, write_emva_stacks
    from bayescal.maps.store import make_maps, read_maps, write_maps
    from bayescal.model.assemble import CalibrationModel, build_model
    from bayescal.model.setting import Setting
    from bayescal.model.simulate import Simulation, simulate
    from bayescal.model.spec import ModelSpec, Reference, load_spec
    from bayescal.posterior.calibration import CalibratedRange, Calibration
    from bayescal.prediction.images import invert_image, read_image, write_radiance_maps
    from bayescal.prediction.invert import Inversion, invert, radiance_draws
    from bayescal.prediction.plan import Plan, default_window, plan_exposure
    from bayescal.prediction.readings import predict
    from bayescal.prediction.scene import SceneChoice, choose_for_scene
    from bayescal.report.html import write_report
    from bayescal.validation.design import DesignCheck, check_design
    from bayescal.validation.fleet import FleetDesign, simulate_fleet
    from bayescal.validation.sbc import SBCResult, run_sbc
