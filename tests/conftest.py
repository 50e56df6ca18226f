import os
from pathlib import Path

import pytest

os.environ.setdefault("OMP_NUM_THREADS", "2")

ANCHORS = Path(__file__).resolve().parents[2] / "shared" / "anchors"


@pytest.fixture
def anchors():
    if not ANCHORS.is_dir():
        pytest.skip("shared/anchors not beside the checkout")
    return ANCHORS
