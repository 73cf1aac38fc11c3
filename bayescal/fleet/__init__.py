"""Fleets of cameras of one type, calibrated over campaigns: a two-stage hierarchy.

units (the table split per camera and campaign) -> stage1 (each unit alone, its likelihood
as a Gaussian) -> plan, data, marginal, conditional, sampling (the hierarchy by NUTS) -> posterior (predictions,
drift, recalibration, per-camera calibrations) -> report.  docs/architecture.md, section 8.
"""

from bayescal.fleet.posterior import FleetFit, compare_pooling, fit_fleet
from bayescal.fleet.units import FleetTable, load_fleet_table

__all__ = ["FleetFit", "FleetTable", "compare_pooling", "fit_fleet", "load_fleet_table"]
