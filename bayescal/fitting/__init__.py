"""Fitting: a model and a backend in, a diagnosed fit out (docs/architecture.md, section 4).

fit (one table) and batch (many tables of one structure) run the backends of
:mod:`bayescal.inference`; misfit and holdout check that the model describes its data; select
compares candidate models by PSIS-LOO.
"""
