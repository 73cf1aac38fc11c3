"""Least squares reproduces NIST StRD certified values (>= 9 significant digits)."""

import re

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
