"""Both views' cost volumes in their trees' row layouts (stereobudget.aggregate._pair_volumes)."""

import os
import subprocess
import sys

import numpy as np
import pytest

from stereobudget.fill import filled_sparse_dsi, sparse_dsi_grids
from stereobudget.cost import full_dsi, to_gray
from stereobudget.aggregate import build_tree, tree_layout
from stereobudget.aggregate import pair_cost_rows

DENSE = dict(truncation=7.0, grad_weight=0.89, grad_truncation=2.0)


def _pair(seed=0, h=23, w=57):
    rng = np.random.default_rng(seed)
    left = rng.uniform(0, 255, (h, w, 3)).astype(np.float32)
    right = np.roll(left, -4, axis=1) + rng.normal(0, 3, (h, w, 3)).astype(np.float32)
    return left, np.clip(right, 0, 255).astype(np.float32)


def _layouts(left, right):
    return (tree_layout(build_tree(left, median_size=0)), tree_layout(build_tree(right, median_size=0)))


@pytest.mark.parametrize("min_disp, num_disp", [(0, 12), (-3, 9), (5, 7), (0, 70),
                                                (0, 16), (-5, 8), (3, 24), (0, 32), (-9, 16)])
def test_dense_rows_are_the_full_dsi_and_its_diagonals(min_disp, num_disp, right_view_reference):
    # num_disp 70 > width: every right pixel's diagonal leaves the image on both sides.
    # Multiples of 8 layers: blocks of 8 x 8 inside the image are copied as vectors, the
    # blocks near the borders element by element; both must give the diagonals.
    left, right = _pair()
    left_layout, right_layout = _layouts(left, right)
    expected = full_dsi(left, right, min_disp=min_disp, num_disp=num_disp, **DENSE)
    left_rows, right_rows = pair_cost_rows(left, right, min_disp=min_disp, num_disp=num_disp, **DENSE,
                                           left_layout=left_layout, right_layout=right_layout)
    np.testing.assert_array_equal(left_rows, expected.reshape(-1, num_disp)[left_layout.pixel_of_row])
    right_expected = right_view_reference(expected, min_disp).reshape(-1, num_disp)
    np.testing.assert_array_equal(right_rows, right_expected[right_layout.pixel_of_row])


def test_without_a_right_layout_only_the_left_view_is_made():
    left, right = _pair(1)
    left_layout, _ = _layouts(left, right)
    left_rows, right_rows = pair_cost_rows(left, right, min_disp=0, num_disp=6, **DENSE, left_layout=left_layout)
    assert right_rows is None and left_rows.shape == (left.shape[0] * left.shape[1], 6)


@pytest.mark.parametrize("stride, min_disp", [(3, 0), (4, 2), (3, -2)])
def test_hybrid_rows_are_the_weighted_mean_of_fill_and_dense(stride, min_disp, right_view_reference):
    # A lattice (split grids) with min_disp >= 0, the per-layer grids with a negative one.
    left, right = _pair(2, h=30, w=48)
    guide = to_gray(left)
    rows, cols = np.meshgrid(np.arange(1, 30, stride), np.arange(0, 48, stride), indexing="ij")
    rows, cols = rows.ravel(), cols.ravel()
    values = right[rows, cols]
    num_disp = 11
    fill_args = dict(min_disp=min_disp, num_disp=num_disp, sigma_s=2.0 * stride, sigma_r=15.0, truncation=15.0,
                     cells_per_sigma_s=1.0, cells_per_sigma_r=1.0)
    fill = filled_sparse_dsi(left, guide, rows, cols, values, **fill_args)
    grids = sparse_dsi_grids(left, guide, rows, cols, values, **fill_args)
    weights = (0.7 / 15.0, 0.3 / 2.55)
    left_layout, right_layout = _layouts(left, right)
    left_rows, right_rows = pair_cost_rows(left, right, min_disp=min_disp, num_disp=num_disp, **DENSE,
                                           left_layout=left_layout, right_layout=right_layout, grids=grids,
                                           guide=guide, mix_weights=weights)
    dense = full_dsi(left, right, min_disp=min_disp, num_disp=num_disp, **DENSE)
    # float32 products and sum, each rounded once: the kernel's arithmetic.
    expected = np.float32(weights[0]) * fill + np.float32(weights[1]) * dense
    np.testing.assert_array_equal(left_rows, expected.reshape(-1, num_disp)[left_layout.pixel_of_row])
    right_expected = right_view_reference(expected, min_disp).reshape(-1, num_disp)
    np.testing.assert_array_equal(right_rows, right_expected[right_layout.pixel_of_row])


def test_grids_need_their_guide_and_layer_count():
    left, right = _pair(3)
    guide = to_gray(left)
    rows, cols = np.meshgrid(np.arange(0, 23, 3), np.arange(0, 57, 3), indexing="ij")
    grids = sparse_dsi_grids(left, guide, rows.ravel(), cols.ravel(), right[rows.ravel(), cols.ravel()],
                             min_disp=0, num_disp=5, sigma_s=6.0, sigma_r=15.0, truncation=15.0)
    left_layout, _ = _layouts(left, right)
    with pytest.raises(ValueError, match="layers"):
        pair_cost_rows(left, right, min_disp=0, num_disp=6, **DENSE, left_layout=left_layout, grids=grids,
                       guide=guide)


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


def test_decodes_in_one_process_give_the_same_disparity_with_recycled_volumes():
    # The second decode runs on the first one's volumes (uninitialised memory that held
    # its costs): every value must be written again, so the results are identical.
    import stereobudget
    from stereobudget._kernels import _scratch as scratch
    from stereobudget.io import encode_image
    from stereobudget.sampling import SamplingPattern
    from stereobudget.scenes import make_scene
    scene = make_scene("slanted", height=48, width=64, max_disp=12, seed=3)
    samples = encode_image(scene.right, pattern=SamplingPattern("grid", 4, 4))
    scratch.release()
    for method in ("hybrid", "sparse"):
        first = stereobudget.decode(scene.left, samples, max_disp=12, method=method).disparity
        assert scratch._spare, "the decode handed its volumes back"
        for _, spare in scratch._spare:
            spare.fill(np.nan)                         # poison: any value not rewritten shows
        second = stereobudget.decode(scene.left, samples, max_disp=12, method=method).disparity
        np.testing.assert_array_equal(first, second)
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


@pytest.mark.parametrize("shape", [(1, 1), (4, 2), (5, 3), (23, 57)])
def test_gradient_taken_in_the_kernels_is_the_gradient_image(shape):
    # The cost kernels take I1's and I2's x-gradients pixel by pixel (cost.gradient_at);
    # they must be horizontal_gradient's values, bit for bit.
    from numba import njit

    from stereobudget.cost import gradient_at, horizontal_gradient

    @njit
    def every_pixel(gray):
        out = np.empty(gray.shape, np.float32)
        for y in range(gray.shape[0]):
            for x in range(gray.shape[1]):
                out[y, x] = gradient_at(gray, y, x)
        return out

    gray = np.random.default_rng(5).uniform(0, 255, shape).astype(np.float32)
    np.testing.assert_array_equal(every_pixel(gray), horizontal_gradient(gray))
