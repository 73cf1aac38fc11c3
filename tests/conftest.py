import gc
from pathlib import Path

import pytest

import bayescal as bc

ROOT = Path(__file__).resolve().parent.parent
#: reference data (real CCD, NIST StRD) shipped with the tests, with their licences (tests/data/README.md)
DATA = ROOT / "tests" / "data"
MODELS = ROOT / "models"


@pytest.fixture(scope="session")
def seed000():
    spec = bc.load_spec(MODELS / "seed000_bayer.toml")
    design = bc.load_design(MODELS / "seed000_design.toml")
    return spec, design


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop every compiled program after each test module, so the run's memory stays bounded.

    Programs are cached per model structure for speed within a process; a test run builds
    hundreds of structures, which would otherwise all stay resident.
    """
    yield
    from bayescal._caches import clear_caches

    clear_caches()
    gc.collect()
