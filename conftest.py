"""Fixtures shared by several test modules, and a guard against stale compiled kernels."""

import hashlib
import importlib.util
import os
from pathlib import Path

import numpy as np
import pytest


def _drop_stale_numba_caches():
    """Delete the package's numba cache files when any of its library sources changed since the last run.

    numba checks a cached kernel against its own source file only.  Many kernels inline
    functions of other modules (``volumes._pair_rows`` inlines the bilateral slice), so
    after an edit to those a working copy would run, and test, the old compiled code.
    The fingerprint of every library source file is kept beside the cache; when it differs, the
    whole cache goes and the kernels are compiled afresh.  A fresh clone has no cache and
    is not affected; nor is a cache moved elsewhere with NUMBA_CACHE_DIR (not handled here).
    """
    spec = importlib.util.find_spec("stereobudget")
    if spec is None or not spec.submodule_search_locations or os.environ.get("NUMBA_CACHE_DIR"):
        return
    package = Path(next(iter(spec.submodule_search_locations)))
    caches = list(package.rglob("__pycache__"))
    digest = hashlib.sha256()
    # Test files hold no cached kernels: editing one must not cost a recompile of everything.
    sources = [path for path in package.rglob("*.py") if "tests" not in path.relative_to(package).parts]
    for source in sorted(sources):
        digest.update(str(source).encode() + b"\0" + source.read_bytes())
    stamp = package / "__pycache__" / "numba-sources.sha256"
    try:
        if stamp.exists() and stamp.read_text() == digest.hexdigest():
            return
        for cache in caches:
            for compiled in [*cache.glob("*.nbi"), *cache.glob("*.nbc")]:
                compiled.unlink(missing_ok=True)
        stamp.parent.mkdir(exist_ok=True)
        stamp.write_text(digest.hexdigest())
    except OSError:  # a read-only install: numba keeps its cache elsewhere
        return


_drop_stale_numba_caches()


def _right_view_reference(left_cost, min_disp):
    """C_R(x, d) = C_L(x + d, d), the border column where x + d leaves the image (numpy)."""
    h, w, nd = left_cost.shape
    columns = np.clip(np.arange(w)[:, None] + min_disp + np.arange(nd)[None, :], 0, w - 1)
    return left_cost[:, columns, np.arange(nd)[None, :]]


@pytest.fixture
def right_view_reference():
    """The right view's cost volume from the left one, by plain numpy indexing."""
    return _right_view_reference
