"""DEM physics: pure @njit kernels over structure-of-arrays state (never imports modes/, bench/, mpi4py).

Numba's on-disk cache (cache=True) re-checks only the source file that defines a function, not
the modules whose kernels it calls, so an edit to one kernel can leave stale machine code in its
callers' caches (seen here: a threaded driver kept an old derive_particle). The cache therefore
lives in a folder keyed by a hash of every source file of dem/ and modes/:
$NUMBA_CACHE_DIR when the user set it, else ~/.cache/dem-mapping-bench/numba/<hash>. This runs
before any kernel is defined (modes/ and bench/ import dem first). It does not import numba
(through the variable, read when numba starts), so that a command can import dem's plain names
before it sets the thread variables numba reads at import (bench.run.threads_env).
"""
import hashlib
import os
import sys


def _source_key(root=None):
    """Hash [16 hex digits] of the names and contents of the .py files of dem/ and modes/ under root
    (default: this checkout)."""
    root = root or os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    h = hashlib.sha256()
    for pkg in ("dem", "modes"):
        for folder, dirs, files in sorted(os.walk(os.path.join(root, pkg))):
            dirs.sort()
            for f in sorted(files):
                if f.endswith(".py"):
                    path = os.path.join(folder, f)
                    h.update(os.path.relpath(path, root).encode())
                    with open(path, "rb") as fh:
                        h.update(fh.read())
    return h.hexdigest()[:16]


if "NUMBA_CACHE_DIR" not in os.environ:
    _cache = os.path.join(os.path.expanduser("~"), ".cache", "dem-mapping-bench", "numba", _source_key())
    if "numba" in sys.modules:  # numba started before dem: tell its config directly
        sys.modules["numba"].config.CACHE_DIR = _cache
    else:
        os.environ["NUMBA_CACHE_DIR"] = _cache
