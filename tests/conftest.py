import os
from pathlib import Path

import pytest

import bayescal as bc

ROOT = Path(__file__).resolve().parent.parent
#: the project's reference data (real CCD, NIST StRD) live beside the checkout; BAYESCAL_SHARED_DATA overrides
SHARED = Path(os.environ.get("BAYESCAL_SHARED_DATA", ROOT.parent / "shared" / "data"))
MODELS = ROOT / "models"


@pytest.fixture(scope="session")
def seed000():
    spec = bc.load_spec(MODELS / "seed000_bayer.toml")
    design = bc.load_design(MODELS / "seed000_design.toml")
    return spec, design
