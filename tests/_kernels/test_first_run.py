"""The first-compile notice, in real processes: announced once on an empty kernel cache, and not
again once the default decoder has run."""

from __future__ import annotations

import os
import subprocess
import sys


def run(code, *, env=None):
    # No time limit: on an empty cache the decode compiles every kernel, which takes minutes on a
    # busy machine, and what is asserted is the notice, not how long the compile takes.
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=dict(os.environ, **(env or {})))


def test_empty_kernel_cache_is_announced_once(tmp_path):
    code = ("import logging, sys; logging.basicConfig(stream=sys.stderr, format='%(message)s');"
            "from stereobudget._kernels._first_run import announce_first_compile, kernels_cached;"
            "print(kernels_cached()); print(announce_first_compile())")
    fresh = run(code, env={"NUMBA_CACHE_DIR": str(tmp_path / "empty")})
    assert fresh.returncode == 0, fresh.stderr
    assert fresh.stdout.split() == ["False", "True"]
    lines = fresh.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("compiling kernels, first run only, ~") and lines[0].endswith(" s")


def test_after_a_default_decode_the_kernels_count_as_cached():
    # The notice must not reappear once the default decoder has run (it probes the
    # modules that decoder compiles, not only the paper's tree route).
    decode = ("import numpy as np; from stereobudget import decode; from stereobudget.encoding import encode_image;"
              "from stereobudget.sampling import SamplingPattern; from stereobudget.scenes import make_scene;"
              "s = make_scene('slanted', height=48, width=64, max_disp=8);"
              "decode(s.left, encode_image(s.right, pattern=SamplingPattern('grid', 5, 5)), max_disp=8)")
    assert run(decode).returncode == 0
    probe = run("from stereobudget._kernels._first_run import kernels_cached; print(kernels_cached())")
    assert probe.returncode == 0 and probe.stdout.split() == ["True"], probe.stderr
