from pathlib import Path

import pytest

import bayescal as bc

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "data"
MODELS = ROOT / "models"


@pytest.fixture(scope="session")
def seed000():
    spec = bc.load_spec(MODELS / "seed000_bayer.toml")
    design = bc.load_design(MODELS / "seed000_design.toml")
    return spec, design
