"""The README's Python example runs as written (doctest), on the demo pair it tells users to make."""

from __future__ import annotations

import doctest
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[2] / "README.md"


@pytest.mark.skipif(not README.is_file(), reason="README.md is not beside the package (an installed copy)")
def test_readme_python_example(tmp_path, monkeypatch):
    from stereobudget.demo import write_demo_pair

    write_demo_pair(tmp_path / "demo")
    monkeypatch.chdir(tmp_path / "demo")     # the example runs in the demo folder
    result = doctest.testfile(str(README), module_relative=False, optionflags=doctest.ELLIPSIS,
                              raise_on_error=False, verbose=False)
    assert result.attempted >= 10 and result.failed == 0, result
    assert (tmp_path / "demo" / "disparity.pfm").is_file() and (tmp_path / "demo" / "right_recovered.png").is_file()
