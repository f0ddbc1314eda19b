"""The README's Python example runs as written (doctest), on the demo pair it tells users to make; its first
shell command runs again over the files of an earlier run."""

from __future__ import annotations

import doctest
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


@pytest.mark.skipif(not README.is_file(), reason="README.md is not beside the package (an installed copy)")
def test_readme_python_example(tmp_path, monkeypatch):
    from stereobudget.demo import write_demo_pair

    write_demo_pair(tmp_path / "demo")
    monkeypatch.chdir(tmp_path / "demo")     # the example runs in the demo folder
    result = doctest.testfile(str(README), module_relative=False, optionflags=doctest.ELLIPSIS,
                              raise_on_error=False, verbose=False)
    assert result.attempted >= 10 and result.failed == 0, result
    assert (tmp_path / "demo" / "disparity.pfm").is_file() and (tmp_path / "demo" / "right_recovered.png").is_file()


def _first_shell_command() -> str:
    text = README.read_text()
    block = text[text.index("```sh\n") + len("```sh\n"):]
    return block[:block.index("\n```")].strip()


@pytest.mark.skipif(not README.is_file(), reason="README.md is not beside the package (an installed copy)")
def test_readme_first_command_runs_again_over_its_own_outputs(tmp_path):
    # The command after the install, with this environment's scripts; every output of an earlier run
    # is already there (the second run used to stop at "output exists").
    command = _first_shell_command()
    steps = command.split(" && ")
    assert steps[:2] == ["python3 -m venv .venv", ".venv/bin/pip install ."], steps
    bin_dir = Path(sys.executable).parent
    rerun = " && ".join(steps[2:]).replace(".venv/bin/", f"{bin_dir}/")
    from stereobudget.demo import write_demo_pair

    write_demo_pair(tmp_path / "demo")
    for name in ("right.sbs", "disparity.pfm", "right_recovered.png", "preview.png"):
        (tmp_path / "demo" / name).write_bytes(b"from an earlier run")
    proc = subprocess.run(["sh", "-c", rerun], cwd=tmp_path, capture_output=True, text=True, timeout=3600)
    assert proc.returncode == 0, proc.stderr
    from stereobudget.io import MAGIC, read_disparity

    assert (tmp_path / "demo" / "right.sbs").read_bytes().startswith(MAGIC)
    assert read_disparity(tmp_path / "demo" / "disparity.pfm").shape == (240, 320)
