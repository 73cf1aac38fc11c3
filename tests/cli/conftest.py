import pytest

import bayescal as bc


@pytest.fixture(scope="module")
def good_csv(tmp_path_factory, seed000):
    """A well-formed measurement table of the seed 000 camera (the model's own simulator), as a file."""
    spec, design = seed000
    path = tmp_path_factory.mktemp("data") / "good.csv"
    bc.simulate(spec, design, seed=3).table.write_csv(path)
    return path
