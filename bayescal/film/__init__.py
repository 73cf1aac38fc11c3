"""Film density calibration of the 4-band film camera (seed 003): a model kind of its own."""
