"""Planning a calibration campaign before (or while) it is measured: the candidate measurements of a
protocol (grid), what each tells about the calibration (information), how to choose among them (search),
the rows the model's checks need (checks), and the design itself (design)."""
