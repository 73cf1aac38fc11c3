"""Least squares reproduces NIST StRD certified values: linear >= 9 significant digits, nonlinear >= 6 from both
NIST starting points (measured: >= 7.8)."""

import re

import jax.numpy as jnp
import numpy as np
import pytest

from bayescal import polyfit

from .conftest import SHARED


def read_nist(name):
    lines = (SHARED / "nist_strd" / f"{name}.dat").read_text().splitlines()
    cert = {}
    for line in lines:
        m = re.match(r"\s*(B\d+)\s+([-+\dEe.]+)\s+([-+\dEe.]+)", line)
        if m:
            cert[m.group(1)] = (float(m.group(2)), float(m.group(3)))
    number = r"\s+([-+\dEe.]+)\s*$"
    resid_sd = next(float(m.group(1)) for line in lines if (m := re.match(r"\s*Standard Deviation" + number, line)))
    r2 = next(float(m.group(1)) for line in lines if (m := re.match(r"\s*R-Squared" + number, line)))
    start = max(i for i, line in enumerate(lines) if line.strip().startswith("Data:"))
    data = np.array([[float(v) for v in line.split()] for line in lines[start + 1 :] if line.strip()])
    return cert, resid_sd, r2, data


def digits(a, b):
    return np.inf if a == b else -np.log10(abs(a - b) / abs(b))


@pytest.mark.parametrize("name,order", [("Norris", 1), ("Pontius", 2), ("Wampler2", 5), ("Wampler1", 5)])
def test_certified_values(name, order):
    cert, resid_sd, r2, data = read_nist(name)
    fit = polyfit(data[:, 1], data[:, 0], order)
    for k in range(order + 1):
        value, sd = cert[f"B{k}"]
        assert digits(fit.coef[k], value) >= 9, (k, fit.coef[k], value)
        if sd != 0:
            assert digits(fit.se[k], sd) >= 9
    if resid_sd != 0:
        assert digits(fit.rmse, resid_sd) >= 9
    assert digits(fit.r2, r2) >= 9


def test_longley_and_no_intercept():
    from bayescal import lstsq

    cert, resid_sd, r2, data = read_nist("Longley")
    design = np.column_stack([np.ones(len(data)), data[:, 1:]])  # 6 collinear predictors
    fit = lstsq(design, data[:, 0])
    for k in range(7):
        value, sd = cert[f"B{k}"]
        assert digits(fit.coef[k], value) >= 9 and digits(fit.se[k], sd) >= 9, k
    assert digits(fit.rmse, resid_sd) >= 9
    for name in ("NoInt1", "NoInt2"):
        cert, resid_sd, _, data = read_nist(name)
        fit = polyfit(data[:, 1], data[:, 0], 1, intercept=False)
        value, sd = cert["B1"]
        assert digits(fit.coef[-1], value) >= 9 and digits(fit.se[-1], sd) >= 9, name


NONLINEAR = {
    "Misra1a": lambda b, x: b[0] * (1 - jnp.exp(-b[1] * x)),
    "Misra1b": lambda b, x: b[0] * (1 - (1 + b[1] * x / 2) ** (-2)),
    "BoxBOD": lambda b, x: b[0] * (1 - jnp.exp(-b[1] * x)),
    "Eckerle4": lambda b, x: (b[0] / b[1]) * jnp.exp(-0.5 * ((x - b[2]) / b[1]) ** 2),
    "MGH09": lambda b, x: b[0] * (x**2 + x * b[1]) / (x**2 + x * b[2] + b[3]),
    "Rat43": lambda b, x: b[0] / ((1 + jnp.exp(b[1] - b[2] * x)) ** (1 / b[3])),
    "DanWood": lambda b, x: b[0] * x ** b[1],
    "Chwirut2": lambda b, x: jnp.exp(-b[0] * x) / (b[1] + b[2] * x),
}


def read_nonlinear(name):
    lines = (SHARED / "nist_strd" / f"{name}.dat").read_text().splitlines()
    rows = [line.split() for line in lines if re.match(r"\s*b\d+\s*=", line)]
    starts = [np.array([float(r[i]) for r in rows]) for i in (2, 3)]
    cert, sd = (np.array([float(r[i]) for r in rows]) for i in (4, 5))
    first = max(i for i, line in enumerate(lines) if line.strip().startswith("Data:"))
    data = np.array([[float(v) for v in line.split()] for line in lines[first + 1 :] if line.strip()])
    return starts, cert, sd, data


@pytest.mark.parametrize("name", sorted(NONLINEAR))
def test_nonlinear_certified_from_both_starts(name):
    from bayescal.inference.nls import nonlinear_lsq

    starts, cert, sd, data = read_nonlinear(name)
    for start in starts:
        fit = nonlinear_lsq(NONLINEAR[name], data[:, 1], data[:, 0], start)
        assert fit.converged, (name, start)
        assert min(digits(a, b) for a, b in zip(fit.coef, cert, strict=True)) >= 6, (name, start, fit.coef)
        # the Gaussian at the optimum (flat prior, scale profiled) has the certified standard deviations
        assert min(digits(a, b) for a, b in zip(fit.se, sd, strict=True)) >= 6, (name, start)
