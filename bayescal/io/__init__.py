"""Inputs and files: what comes in (measurement tables, experiment designs, EMVA 1288 data,
images, colour filter arrays) and how results go out (atomic writes, staged directories).

Everything here validates what it reads and names the file, row, column or key of a bad
input (:class:`~bayescal.errors.TableError`, :class:`~bayescal.errors.SpecError`); nothing
here knows the calibration model.
"""
