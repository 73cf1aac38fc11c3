"""A fit's folder: each file read once, and clear errors for what is not a fit's."""

import numpy as np
import pytest
import xarray as xr

from bayescal.errors import PosteriorError
from bayescal.io.fit_folder import FitFolder


def test_the_posterior_is_opened_once_and_a_stray_file_has_no_summary(tmp_path):
    path = tmp_path / "draws.nc"
    xr.DataTree(xr.Dataset({"a": ("x", np.arange(3.0))})).to_netcdf(path, engine="h5netcdf")
    folder = FitFolder.at(path)
    assert folder.root is None and folder.posterior is folder.posterior  # one open file, kept
    np.testing.assert_array_equal(folder.posterior["a"].values, [0.0, 1.0, 2.0])
    with pytest.raises(PosteriorError, match="is not in a fit folder: it has no summary.json"):
        folder.summary  # noqa: B018


def test_a_truncated_posterior_is_named(tmp_path):
    path = tmp_path / "posterior.nc"
    path.write_bytes(b"\x89HDF\r\n\x1a\n truncated")
    with pytest.raises(PosteriorError, match=r"posterior.nc is not a readable posterior file .* truncated"):
        FitFolder.at(path).posterior  # noqa: B018
    with pytest.raises(PosteriorError, match="no posterior at"):
        FitFolder.at(tmp_path / "nowhere")
