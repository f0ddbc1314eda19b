"""Fixtures shared by several test modules, and a guard against stale compiled kernels."""

import hashlib
import importlib.util
import os
from pathlib import Path

import numpy as np
import pytest


def _imported_modules(path, package, root):
    """Library files that ``path`` imports (relative or ``stereobudget.`` imports); a package means all its files."""
    import ast

    try:
        tree = ast.parse(path.read_bytes())
    except SyntaxError:
        return set()
    here = path.parent.relative_to(root).parts
    targets = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = here[:len(here) - node.level + 1] + tuple((node.module or "").split(".") if node.module else ())
            elif (node.module or "").split(".")[0] == package.name:
                base = tuple(node.module.split("."))
            else:
                continue
            targets.add(base)
            targets.update(base + (alias.name,) for alias in node.names)
        elif isinstance(node, ast.Import):
            targets.update(tuple(a.name.split(".")) for a in node.names if a.name.split(".")[0] == package.name)
    files = set()
    for parts in targets:
        module = root.joinpath(*parts)
        if module.with_suffix(".py").is_file():
            files.add(module.with_suffix(".py"))
        elif module.is_dir():
            # Through a package's lazy __init__ any of its modules may be reached.
            files.update(f for f in module.rglob("*.py") if "tests" not in f.relative_to(module).parts)
    return files


def _drop_stale_numba_caches():
    """Delete the compiled kernels of modules whose own source, or a source they import, changed.

    numba checks a cached kernel against its own source file only.  Many kernels inline
    functions of other modules (the cost volumes inline the bilateral slice), so after an
    edit to those a working copy would run, and test, the old compiled code.  A digest of
    every library file is kept beside the cache; the kernels of each changed file and of
    every file importing it (directly or not) are dropped and compiled afresh, the rest are
    kept.  Test files hold no kernels and are not tracked.  A fresh clone has no cache and
    is not affected; nor is a cache moved elsewhere with NUMBA_CACHE_DIR (not handled here).
    """
    import json

    spec = importlib.util.find_spec("stereobudget")
    if spec is None or not spec.submodule_search_locations or os.environ.get("NUMBA_CACHE_DIR"):
        return
    package = Path(next(iter(spec.submodule_search_locations)))
    root = package.parent
    sources = sorted(p for p in package.rglob("*.py") if "tests" not in p.relative_to(package).parts)
    digests = {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() for p in sources}
    stamp = package / "__pycache__" / "numba-sources.json"
    try:
        known = json.loads(stamp.read_text()) if stamp.exists() else {}
    except (OSError, ValueError):
        known = {}
    changed = {root / name for name, digest in digests.items() if known.get(name) != digest}
    if not changed and set(known) == set(digests):
        return
    importers = {}
    for source in sources:
        for imported in _imported_modules(source, package, root):
            importers.setdefault(imported, set()).add(source)
    stale, todo = set(), list(changed)
    while todo:
        source = todo.pop()
        if source not in stale:
            stale.add(source)
            todo.extend(importers.get(source, ()))
    try:
        for source in stale:
            cache = source.parent / "__pycache__"
            for compiled in [*cache.glob(f"{source.stem}.*.nbi"), *cache.glob(f"{source.stem}.*.nbc")]:
                compiled.unlink(missing_ok=True)
        stamp.parent.mkdir(exist_ok=True)
        stamp.write_text(json.dumps(digests, indent=0, sort_keys=True))
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


#: (width, height) of the frames of :func:`camera_frames`.
CAMERA_FRAME_SIZE = (96, 64)


@pytest.fixture(scope="module")
def camera_frames(tmp_path_factory):
    """A folder holding a camera's three frames: left images L/0..2.png, the right images
    r0..2.png, and the right camera's raw rgb24 frames one after another in rights.raw."""
    import cv2

    from stereobudget.scenes import make_scene

    folder = tmp_path_factory.mktemp("camera")
    (folder / "L").mkdir()
    rights = []
    width, height = CAMERA_FRAME_SIZE
    for index, kind in enumerate(("slanted", "planes", "fine_texture")):
        scene = make_scene(kind, height=height, width=width, max_disp=16, seed=index)
        assert cv2.imwrite(str(folder / "L" / f"{index}.png"), np.ascontiguousarray(scene.left[:, :, ::-1]))
        assert cv2.imwrite(str(folder / f"r{index}.png"), np.ascontiguousarray(scene.right[:, :, ::-1]))
        rights.append(np.ascontiguousarray(scene.right).tobytes())
    (folder / "rights.raw").write_bytes(b"".join(rights))
    return folder
