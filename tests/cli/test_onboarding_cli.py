"""First steps of a new user, in real processes: shell completion (the first-compile notice is tested in
tests/_kernels/test_first_run.py)."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile


def run(code_or_args, *, env=None, module=False):
    args = [sys.executable, "-m", *code_or_args] if module else [sys.executable, "-c", code_or_args]
    # Away from the repository root, whose source folder would shadow the installed package
    # (the commands install as stereobudget.cli from the top-level cli/ folder).
    return subprocess.run(args, capture_output=True, text=True, timeout=1800, env=dict(os.environ, **(env or {})),
                          cwd=tempfile.gettempdir())


def test_bash_completion_of_options_and_choices():
    env = {"_SB_DECODE_COMPLETE": "bash_source"}
    script = run(["stereobudget.cli.decode"], module=True, env=env)
    assert script.returncode == 0 and "_sb_decode_completion" in script.stdout
    # What bash asks while the user types `sb-decode --max<TAB>` and `--method <TAB>`.
    options = run(["stereobudget.cli.decode"], module=True,
                  env={"_SB_DECODE_COMPLETE": "bash_complete", "COMP_WORDS": "sb-decode --max", "COMP_CWORD": "1"})
    assert "plain,--max-disp" in options.stdout.splitlines()
    methods = run(["stereobudget.cli.decode"], module=True,
                  env={"_SB_DECODE_COMPLETE": "bash_complete", "COMP_WORDS": "sb-decode --method ", "COMP_CWORD": "2"})
    assert [line.split(",")[1] for line in methods.stdout.splitlines()] == ["hybrid", "sparse", "downsample", "full"]


