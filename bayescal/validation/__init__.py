"""Validation against data the model did not generate (docs: "Validation").

:mod:`bayescal.validation.bench` simulates a calibration bench and camera
written apart from the model code: it imports nothing from bayescal's
components, so it cannot share their assumptions, and it carries realistic
departures from them that can be switched on one by one.
"""

from bayescal.validation.bench import BenchCamera, Departures, Realisation, simulate_bench, with_held_out

__all__ = ["BenchCamera", "Departures", "Realisation", "simulate_bench", "with_held_out"]
