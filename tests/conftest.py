import os
import sys

# before numba starts: room for 3 threads (more than a 2-core machine has: correctness only),
# and passive waiting so oversubscribed OpenMP threads do not spin
os.environ.setdefault("NUMBA_NUM_THREADS", "3")
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
