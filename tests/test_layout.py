"""The repository's layout rules, checked on its sources.

- The top level is ``stereobudget/`` (the library), ``cli/`` (the commands, installed as
  ``stereobudget.cli``), ``tests/`` (mirroring the package: ``tests/<topic>/`` for
  ``stereobudget/<topic>/``, ``tests/cli/``, ``tests/scripts/``) and ``scripts/``; no test lives in
  an installed folder, and ``pyproject.toml`` lists every package.
- No import cycles: the modules imported at module level form a directed acyclic graph.
- Tests hold behaviour through public names. A test file may name a private module or helper
  (a name with one leading underscore) only if it is a white-box test of one module, named
  ``test_<module>_internals.py`` (it is rewritten or deleted with that module, whose behaviour
  another test holds to a reference through a public entry point), or if it lives in
  ``tests/_kernels`` (the speed tricks' own tests), or if it is listed in ``PRIVATE_ALLOWED``
  below with its reason. Any other kernel can then be rewritten or deleted without touching tests.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "stereobudget"
CLI = REPO / "cli"            # installed as stereobudget.cli
TESTS = REPO / "tests"

# test file (relative to tests/) -> {private module or attribute it may name: why}
PRIVATE_ALLOWED = {
    "decoding/test_decoder.py": {
        "_kernels": "holds _scratch",
        "_scratch": "the pools and the allocator setting a Decoder owns live there; the tests check "
                    "that a plain decode leaves them as it found them",
        "_frames": "the count of open decoders, which a test resets to see a fresh process",
        "_malloc_tuned": "reset to see a fresh process",
        "_take_spare": "counted to show a second decode runs on the first one's volumes",
        "_spare": "poisoned to show every reused value is rewritten",
        "_large": "to show only the small volumes are kept without kept memory",
    },
    "decoding/test_tiling.py": {
        "_kernels": "holds _scratch",
        "_scratch": "the volume pools: the test shows bands hand their large volumes back to the system",
        "_frames": "the count of open decoders, reset so a shared decoder of other tests does not keep volumes",
        "_large": "the large spares, which no band may hold beside its own volumes",
    },
    "batch/test_batch.py": {
        "_kernels": "holds _scratch",
        "_scratch": "the volume pools: the test shows a dask client's thread workers hand back what their "
                    "decodes kept once the batch ends",
    },
}


def _module_name(path: Path) -> str:
    if path.is_relative_to(CLI):
        parts = ["stereobudget", "cli", *path.relative_to(CLI).with_suffix("").parts]
    else:
        parts = list(path.relative_to(REPO).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _library_files():
    return sorted(PACKAGE.rglob("*.py")) + sorted(CLI.rglob("*.py"))


def _test_files():
    return sorted(TESTS.rglob("test_*.py"))


def _source_folder(topic: str) -> Path:
    """The library folder that ``tests/<topic>/`` mirrors."""
    return CLI if topic == "cli" else PACKAGE / topic


def _listed_packages() -> set[str]:
    import tomllib

    return set(tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])


def test_pyproject_lists_every_package_and_no_test_folder():
    packages = {_module_name(init) for init in _library_files() if init.name == "__init__.py"}
    assert _listed_packages() == packages


def test_no_tests_inside_installed_folders():
    stray = [path.relative_to(REPO).as_posix() for folder in (PACKAGE, CLI)
             for path in folder.rglob("*.py") if "tests" in path.relative_to(folder).parts
             or path.name.startswith("test_")]
    assert not stray, f"tests belong under tests/, not in an installed folder: {stray}"


def test_tests_mirror_the_package():
    for folder in sorted(path for path in TESTS.iterdir() if path.is_dir() and path.name != "__pycache__"):
        if folder.name == "scripts":
            assert (REPO / "scripts").is_dir()
            continue
        assert (_source_folder(folder.name) / "__init__.py").is_file(), (
            f"tests/{folder.name}/ mirrors no subpackage stereobudget/{folder.name}/")


def _resolve(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    base = module.split(".")
    if not is_package:
        base = base[:-1]
    base = base[:len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _executed_on_import(body):
    """Statements run when the module is imported: not function bodies, not ``if TYPE_CHECKING:``."""
    for statement in body:
        if isinstance(statement, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        if isinstance(statement, ast.If):
            if isinstance(statement.test, ast.Name) and statement.test.id == "TYPE_CHECKING":
                yield from _executed_on_import(statement.orelse)
                continue
            yield from _executed_on_import(statement.body + statement.orelse)
        elif isinstance(statement, ast.Try):
            yield from _executed_on_import(statement.body + statement.orelse + statement.finalbody
                                           + [line for handler in statement.handlers for line in handler.body])
        elif isinstance(statement, (ast.With, ast.ClassDef)):
            yield from _executed_on_import(statement.body)
        else:
            yield statement


def _module_level_imports(path: Path, known: set[str]) -> set[str]:
    """Package modules that ``path`` imports when it is itself imported (not inside functions)."""
    module = _module_name(path)
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = set()
    for statement in _executed_on_import(tree.body):
        if isinstance(statement, ast.Import):
            names = [alias.name for alias in statement.names]
        elif isinstance(statement, ast.ImportFrom):
            target = _resolve(module, path.name == "__init__.py", statement)
            names = [target] + [f"{target}.{alias.name}" for alias in statement.names]
        else:
            continue
        found.update(name for name in names if name in known and name != module)
    return found


def test_modules_import_each_other_without_cycles():
    files = _library_files()
    known = {_module_name(path) for path in files}
    graph = {_module_name(path): _module_level_imports(path, known) for path in files}
    state: dict[str, int] = {}          # 1: on the current path, 2: finished
    path: list[str] = []

    def visit(node):
        state[node] = 1
        path.append(node)
        for child in sorted(graph[node]):
            if state.get(child) == 1:
                cycle = path[path.index(child):] + [child]
                raise AssertionError("import cycle: " + " -> ".join(cycle))
            if child not in state:
                visit(child)
        path.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node)


_DOTTED_PACKAGE_PATH = re.compile(r"\bstereobudget(?:\.\w+)+")


def _private_names(path: Path) -> set[str]:
    """Private package modules and private attributes a test file names.

    Imports and attribute accesses count, and so do strings: a module path given to
    ``importlib`` or written into a child process's code (the file's docstring excepted).
    """
    tree = ast.parse(path.read_text(encoding="utf-8"))
    docstring = ast.get_docstring(tree, clean=False)
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value != docstring:
            for dotted in _DOTTED_PACKAGE_PATH.findall(node.value):
                names.update(part for part in dotted.split(".") if part.startswith("_") and not part.startswith("__"))
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "stereobudget":
            names.update(part for part in node.module.split(".") if part.startswith("_"))
            names.update(alias.name for alias in node.names
                         if alias.name.startswith("_") and not alias.name.startswith("__"))
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "stereobudget":
                    names.update(part for part in alias.name.split(".") if part.startswith("_"))
        elif isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__"):
            names.add(node.attr)
        elif isinstance(node, ast.Call) and _called_name(node) in {"setattr", "delattr", "getattr"}:
            # monkeypatch.setattr(module, "_name", ...) names "_name" as surely as module._name does
            names.update(arg.value for arg in node.args[1:2] if isinstance(arg, ast.Constant)
                         and isinstance(arg.value, str) and arg.value.startswith("_")
                         and not arg.value.startswith("__"))
    return names


def _called_name(call: ast.Call) -> str:
    function = call.func
    return function.attr if isinstance(function, ast.Attribute) else getattr(function, "id", "")


def _may_name_private(relative: str) -> bool:
    return relative.startswith("_kernels/") or relative.endswith("_internals.py")


@pytest.mark.parametrize("path", _test_files(), ids=lambda path: str(path.relative_to(TESTS)))
def test_tests_name_only_public_things(path):
    relative = path.relative_to(TESTS).as_posix()
    if _may_name_private(relative):
        return
    allowed = PRIVATE_ALLOWED.get(relative, {})
    unexpected = sorted(_private_names(path) - set(allowed))
    assert not unexpected, (f"{relative} names private {unexpected}: use the subpackage's public names, or move "
                            "white-box tests of one module's helpers to test_<module>_internals.py")


def test_internals_tests_name_a_module_that_exists():
    for path in _test_files():
        if path.name.endswith("_internals.py"):
            module = path.name[len("test_"):-len("_internals.py")]
            source = _source_folder(path.parent.name) / f"_{module}.py"
            assert source.is_file(), f"{path.relative_to(TESTS)}: no {source.relative_to(REPO)} for it to test"


def test_allowed_private_names_are_still_used():
    for relative, allowed in PRIVATE_ALLOWED.items():
        unused = set(allowed) - _private_names(TESTS / relative)
        assert not unused, f"{relative}: PRIVATE_ALLOWED lists {sorted(unused)}, which it no longer names"
