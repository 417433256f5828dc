"""numba's on-disk cache is keyed by the sources of dem/ and modes/ (dem/__init__.py).

numba re-checks only the file that defines a cached function, so an edit to a kernel in one
module left stale machine code in a caller's cache in another (seen: the threaded derive kept an
old derive_particle, and a sphere-ellipsoid contact went missing in threads mode only)."""
import os
import subprocess
import sys

import dem



from tests.helpers import ROOT

def test_cache_folder_follows_the_sources(tmp_path):
    """Without NUMBA_CACHE_DIR, a fresh process caches under ~/.cache/dem-mapping-bench/numba/<key>,
    key = hash of every dem/ and modes/ source; a user's NUMBA_CACHE_DIR is left alone."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(PYTHONPATH=ROOT, HOME=str(tmp_path))
    code = "import dem, numba; print(numba.config.CACHE_DIR)"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == os.path.join(str(tmp_path), ".cache", "dem-mapping-bench", "numba",
                                              dem._source_key())
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "mine")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == str(tmp_path / "mine")


def test_key_changes_with_a_source(tmp_path):
    """The key is a function of file names and contents: a copy of the tree with one kernel file
    edited gets another key, an unedited copy the same one."""
    import shutil
    for pkg in ("dem", "modes"):
        shutil.copytree(os.path.join(ROOT, pkg), tmp_path / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    assert dem._source_key(str(tmp_path)) == dem._source_key()
    with open(tmp_path / "dem" / "integrate.py", "a") as fh:
        fh.write("\n# edited\n")
    assert dem._source_key(str(tmp_path)) != dem._source_key()
