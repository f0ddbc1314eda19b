"""The first-compile notice, in real processes: announced once on an empty kernel cache, and not
again once the default decoder has run; and the second process that compiles a first hybrid
decode's later kernels covers all of them."""

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
    assert len(lines) == 1 and lines[0].startswith("compiling kernels, first run only, ~")
    assert "python -m stereobudget.warm" in lines[0]


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


def test_compiling_during_a_decode_is_announced_once_naming_the_method():
    # numba reports a compile only on a cache miss: a kernel made on the spot always compiles.
    code = ("import logging, sys; logging.basicConfig(stream=sys.stderr, format='%(message)s');"
            "from numba import njit; from stereobudget._kernels._first_run import compile_notice;"
            "f = njit(lambda x: x + 1); g = njit(lambda x: x + 2); h = njit(lambda x: x + 3);"
            "h(1);"                                   # outside a decode: nothing said
            "cm = compile_notice('sparse'); cm.__enter__(); f(1); g(1); cm.__exit__(None, None, None);"
            "cm = compile_notice('hybrid'); cm.__enter__(); g(2.0); cm.__exit__(None, None, None)")
    out = run(code)
    assert out.returncode == 0, out.stderr
    lines = out.stderr.splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith("compiling the sparse decoder's kernels (first use after an install), ~")
    assert "python -m stereobudget.warm" in lines[0]


def test_loading_cached_kernels_says_nothing():
    decode = ("import logging, sys; logging.basicConfig(stream=sys.stderr, format='%(message)s');"
              "from stereobudget import decode; from stereobudget.encoding import encode_image;"
              "from stereobudget.sampling import SamplingPattern; from stereobudget.scenes import make_scene;"
              "s = make_scene('slanted', height=48, width=64, max_disp=8);"
              "decode(s.left, encode_image(s.right, pattern=SamplingPattern('grid', 5, 5)), max_disp=8)")
    assert run(decode).returncode == 0          # compiles what is missing
    again = run(decode)
    assert again.returncode == 0 and "compiling" not in again.stderr, again.stderr


_TAIL_CHECK = """
import numpy as np
from stereobudget import Decoder
from stereobudget.decoding._checks import psnr_at_samples
from stereobudget.encoding import encode_image
from stereobudget.pipeline._jobs import recover_right_image
from stereobudget.sampling._patterns import SamplingPattern
from stereobudget.scenes import make_scene
from stereobudget.warm import warm_hybrid_tail
from numba.core.registry import CPUDispatcher
import importlib

MODULES = ["stereobudget.aggregate._semiglobal", "stereobudget.cost._census", "stereobudget.aggregate._refine",
           "stereobudget.synthesis._warp", "stereobudget.fill._grid"]

def signatures():
    found = set()
    for name in MODULES:
        for key, value in vars(importlib.import_module(name)).items():
            if isinstance(value, CPUDispatcher):
                found.update((name, key, str(sig)) for sig in value.signatures)
    return found

warm_hybrid_tail(kinds=["rgb"])
tail = signatures()
scene = make_scene("planes", height=96, width=160, max_disp=12)
samples = encode_image(scene.right, pattern=SamplingPattern("grid", 5, 5))
disparity = Decoder().decode(scene.left, samples, max_disp=15).disparity
psnr_at_samples(scene.left, disparity, samples)
recover_right_image(scene.left, disparity, samples)
missed = signatures() - tail
print(len(tail), sorted(missed))
"""


def test_the_hybrid_tail_compiles_every_kernel_the_decode_runs_after_its_fill():
    # A fresh process: its kernels hold only the signatures it has run (loaded from the
    # cache or compiled), so a signature the decode adds is one the tail did not cover.
    proc = run(_TAIL_CHECK)
    assert proc.returncode == 0, proc.stderr[-2000:]
    count, missed = proc.stdout.split(" ", 1)
    assert int(count) >= 8 and missed.strip() == "[]"


def test_the_hybrid_tail_runs_in_a_second_process():
    from stereobudget.warm import start_hybrid_tail
    child = start_hybrid_tail("gray")
    assert child is not None and child.wait() == 0
