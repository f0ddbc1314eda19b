"""Spare volumes handed between decodes (stereobudget._kernels._scratch), and the allocator setting."""

import os
import subprocess
import sys

import numpy as np
import pytest

from stereobudget._kernels import _scratch


@pytest.fixture(autouse=True)
def keeping():
    """The pools empty and kept between calls, as inside an open Decoder; emptied again after."""
    _scratch.release()
    _scratch.begin_keeping()
    yield
    _scratch.end_keeping()
    _scratch.release()


def test_spare_volumes_are_reused_only_once_and_within_the_limit(monkeypatch):
    from stereobudget._kernels import _scratch as scratch
    scratch.release()
    first = scratch.empty_volume((10, 7))
    scratch.recycle(first)
    again = scratch.empty_volume((7, 10))             # same size: the spare memory comes back
    assert np.shares_memory(again, first) and again.shape == (7, 10) and again.dtype == np.float32
    assert not np.shares_memory(scratch.empty_volume((7, 10)), first)   # ... to one caller only
    monkeypatch.setattr(scratch, "SPARE_BYTES", 1000)
    monkeypatch.setattr(scratch, "LARGE_BYTES", 1000)
    monkeypatch.setenv("STEREOBUDGET_KEEP_FREED_MEMORY", "0")
    scratch.recycle(np.empty(300, np.float32))         # too large to keep (large spares are off)
    scratch.recycle(np.empty(200, np.float32), np.empty(200, np.float32))   # only the newest fits
    assert [s.size for _, s in scratch._spare] == [200]
    scratch.release()
    assert scratch._spare == []


def _tiny_scratch(monkeypatch, *, large_bytes=1000, keep_large=True):
    """stereobudget._kernels._scratch emptied, with a 1000-byte budget and the given large-volume line."""
    from stereobudget._kernels import _scratch as scratch
    scratch.release()
    monkeypatch.setattr(scratch, "SPARE_BYTES", 1000)
    monkeypatch.setattr(scratch, "LARGE_BYTES", large_bytes)
    if keep_large:
        monkeypatch.delenv("STEREOBUDGET_KEEP_FREED_MEMORY", raising=False)
    else:
        monkeypatch.setenv("STEREOBUDGET_KEEP_FREED_MEMORY", "0")
    return scratch


def test_small_spares_over_the_limit_keep_the_decodes_volume(monkeypatch):
    # A decode takes its big volume back and then recycles a smaller temporary (a blur grid):
    # over the limit, the temporary goes, and the next decode gets the big volume again.
    scratch = _tiny_scratch(monkeypatch, keep_large=False)
    volume = scratch.empty_volume((200,))
    scratch.recycle(volume)
    scratch.recycle(np.empty(10, np.float32), np.empty(20, np.float32))
    assert [s.size for _, s in scratch._spare] == [200, 10, 20]
    assert np.shares_memory(scratch.empty_volume((200,)), volume)
    scratch.recycle(volume)
    scratch.recycle(np.empty(100, np.float32))         # 4 * (10 + 20 + 200 + 100) bytes > 1000
    assert [s.size for _, s in scratch._spare] == [10, 20, 200]   # the largest, then what still fits
    with scratch.frame("another"):                     # a new frame: the old frame's spares go first
        scratch.recycle(np.empty(150, np.float32))
    assert [s.size for _, s in scratch._spare] == [10, 20, 150]
    scratch.release()


def test_large_spares_within_a_frame_survive_misses_and_go_with_another_frame(monkeypatch):
    # A decode may need two large volumes of one size with only one spare: within its
    # frame that miss must not drop the other large spare (its cost volume).
    scratch = _tiny_scratch(monkeypatch)                       # > 250 float32 values is "large"
    with scratch.frame("A"):
        grid, cost = scratch.empty_volume((300,)), scratch.empty_volume((600,))
        scratch.recycle(grid, cost)
    with scratch.frame("A"):
        first = scratch.empty_volume((300,))
        second = scratch.empty_volume((300,))                  # a miss: allocated, nothing dropped
        assert np.shares_memory(first, grid) and not np.shares_memory(second, grid)
        assert np.shares_memory(scratch.empty_volume((600,)), cost)
        scratch.recycle(first, second, cost)
    assert scratch.spare_bytes() == 4 * 1200
    with scratch.frame("A"):                                   # takes one 300: the spares it left go after it
        scratch.recycle(scratch.empty_volume((300,)))
    assert [spare.size for spare in scratch._large] == [300]
    with scratch.frame("B"):                                   # another frame: the spares go first
        assert scratch.spare_bytes() == 0
    scratch.release()


def test_a_frames_large_volume_leaves_the_budget_to_its_smaller_ones(monkeypatch):
    # Over LARGE_BYTES a volume is the frame's own and is kept outside the SPARE_BYTES
    # budget, which then holds the decode's grids instead of being filled by that volume.
    scratch = _tiny_scratch(monkeypatch, large_bytes=400)      # > 100 float32 values is "large"
    with scratch.frame("A"):
        scratch.recycle(np.empty(240, np.float32), np.empty(100, np.float32), np.empty(100, np.float32))
    assert [s.size for s in scratch._large] == [240]
    assert [s.size for _, s in scratch._spare] == [100, 100]
    assert scratch.spare_bytes() == 4 * 440
    scratch.release()


def test_new_volumes_start_a_cache_line_and_hold_what_is_asked():
    # Rows of whole cache lines then start lines, and a row's prefetch asks for exactly those.
    from stereobudget._kernels import _scratch as scratch
    scratch.release()
    for shape in [(5, 64), (1, 1), (3, 7), (100, 16)]:
        volume = scratch.empty_volume(shape)
        assert volume.ctypes.data % 64 == 0
        assert volume.shape == shape and volume.dtype == np.float32 and volume.flags.c_contiguous
        volume[...] = 1.0
        assert volume.sum() == np.prod(shape)


def test_large_spares_serve_the_same_size_and_go_before_another_size_is_allocated(monkeypatch):
    # Volumes over LARGE_BYTES (a megapixel frame's) are kept for the next decode of the
    # same size; a large request of another size (another frame size) drops them first,
    # so stale volumes are never held beside new ones.  Small spares are not affected.
    from stereobudget._kernels import _scratch as scratch
    scratch.release()
    monkeypatch.setattr(scratch, "SPARE_BYTES", 1000)
    monkeypatch.setattr(scratch, "LARGE_BYTES", 1000)          # > 250 float32 values is "large"
    monkeypatch.delenv("STEREOBUDGET_KEEP_FREED_MEMORY", raising=False)
    big = scratch.empty_volume((20, 30))
    small = scratch.empty_volume((10, 10))
    scratch.recycle(small, big)
    assert scratch.spare_bytes() == 4 * (600 + 100)
    again = scratch.zeroed_volume((30, 20))
    assert np.shares_memory(again, big) and not again.any()
    scratch.recycle(again)
    scratch.empty_volume((3, 3))                               # a small miss keeps the large spare
    assert scratch.spare_bytes() == 4 * (600 + 100)
    other = scratch.empty_volume((40, 30))                     # a large miss: another frame size
    assert not np.shares_memory(other, big)
    assert scratch.spare_bytes() == 4 * 100                    # only the small spare is left
    scratch.release()
    assert scratch.spare_bytes() == 0


def test_available_memory_counts_the_spares_a_decode_will_take(monkeypatch):
    from stereobudget.io import _limits as limits
    from stereobudget._kernels import _scratch as scratch
    scratch.release()
    monkeypatch.setattr(limits, "_system_available_memory", lambda: 10 ** 9)
    assert limits.available_memory() == 10 ** 9
    scratch.recycle(np.empty(1000, np.float32))
    assert limits.available_memory() == 10 ** 9 + 4000
    monkeypatch.setattr(limits, "_system_available_memory", lambda: None)
    assert limits.available_memory() is None
    scratch.release()


_FAULTS_OF_REPEATED_BLOCKS = """
import resource
import numpy as np
from stereobudget._kernels import _scratch as scratch
tuned = scratch.keep_freed_memory()
faults = []
for size in (3_000_000, 5_000_000, 4_000_000, 5_000_000):   # float32: 12-20 MB, like a decode's temporaries
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    block = np.ones(size, np.float32)
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
    del block
print(sum(faults[2:]), tuned)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="tunes glibc's allocator; Linux only")
def test_kept_freed_memory_spares_repeated_blocks_their_page_faults():
    # Blocks of a decode's sizes, allocated and freed in turn: kept, the later ones reuse
    # the pages of the first; otherwise glibc unmaps or trims them and they fault afresh.
    # (A whole decode's faults also depend on which threads free what, so they are
    # measured in the benchmark, not here.)
    def run(keep):
        env = dict(os.environ, STEREOBUDGET_KEEP_FREED_MEMORY="1" if keep else "0")
        out = subprocess.run([sys.executable, "-c", _FAULTS_OF_REPEATED_BLOCKS], env=env, check=True,
                             capture_output=True, text=True).stdout.split()
        return int(out[0]), out[1] == "True"
    kept_faults, tuned = run(True)
    plain_faults, untouched = run(False)
    assert tuned and not untouched
    assert kept_faults * 4 < plain_faults, (kept_faults, plain_faults)


_HUGE_PAGE_ADVICE = """
import numpy as np
try:
    from numpy._core import multiarray
except ImportError:
    from numpy.core import multiarray
from stereobudget._kernels import _scratch
before = multiarray._get_madvise_hugepage()
print(before, _scratch.avoid_huge_pages(), multiarray._get_madvise_hugepage())
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="numpy advises huge pages on Linux only")
def test_avoiding_huge_pages_turns_numpys_advice_off_unless_the_environment_keeps_it():
    # Process-wide, so in a process of its own.
    def run(**env):
        plain = {key: value for key, value in os.environ.items() if key != "NUMPY_MADVISE_HUGEPAGE"}
        return subprocess.run([sys.executable, "-c", _HUGE_PAGE_ADVICE], env=dict(plain, **env), check=True,
                              capture_output=True, text=True).stdout.split()
    before, turned_off, after = run()
    if before == "False":
        pytest.skip("numpy does not advise huge pages on this kernel")
    assert (turned_off, after) == ("True", "False")
    assert run(NUMPY_MADVISE_HUGEPAGE="1") == ["True", "False", "True"]


def test_volumes_are_kept_between_calls_only_while_someone_keeps_them(monkeypatch):
    # A plain decode runs in_use(): its volumes serve its own later ones, and all go at its end.
    monkeypatch.setattr(_scratch._frames, "keepers", 0)
    _scratch.recycle(np.empty(100, np.float32))
    assert _scratch.spare_bytes() == 0                         # nobody keeps it: freed at once
    with _scratch.in_use():
        volume = _scratch.empty_volume((100,))
        _scratch.recycle(volume)
        assert np.shares_memory(_scratch.empty_volume((100,)), volume)    # reused within the call
        with _scratch.in_use():                                # nested (a tiled decode's bands)
            _scratch.recycle(np.empty(50, np.float32))
        assert _scratch.spare_bytes() == 200
    assert _scratch.spare_bytes() == 0                         # ... and dropped when it ends
    _scratch.begin_keeping()
    with _scratch.in_use():
        _scratch.recycle(np.empty(100, np.float32))
    assert _scratch.spare_bytes() == 400                       # kept for the next call
    _scratch.end_keeping()                                     # the last keeper gives it back
    assert _scratch.spare_bytes() == 0
    with pytest.raises(RuntimeError):
        _scratch.end_keeping()
