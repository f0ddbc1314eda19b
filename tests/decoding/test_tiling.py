"""Tiled decoding: bands with overlap stitched into one disparity map."""

import numpy as np
import pytest

from stereobudget.encoding import encode_image
from stereobudget.decoding import Decoder, auto_tile_rows, decode, decode_tiled
from stereobudget.decoding import band_samples
from stereobudget.errors import OptionError
from stereobudget.decoding import estimate_decode_memory
from stereobudget.sampling import SamplingPattern
from stereobudget.scenes import make_scene


@pytest.fixture(scope="module")
def scene():
    return make_scene("planes", height=120, width=160, max_disp=16, seed=3)


@pytest.mark.parametrize("pattern", [SamplingPattern("grid", 4, 4, 1, 2), SamplingPattern("jitter", 4, 4, seed=5)])
def test_band_samples_are_the_rows_of_the_band(scene, pattern):
    samples = encode_image(scene.right, pattern=pattern)
    rows, cols = samples.positions()
    values = samples.values_rgb()
    band = band_samples(samples, 37, 90)
    band_rows, band_cols = band.positions()
    keep = (rows >= 37) & (rows < 90)
    expected = {(r - 37, c): tuple(v) for r, c, v in zip(rows[keep], cols[keep], values[keep])}
    got = {(r, c): tuple(v) for r, c, v in zip(band_rows, band_cols, band.values_rgb())}
    assert got == expected
    assert (band.height, band.width) == (53, 160)


@pytest.mark.parametrize("method", ["sparse", "hybrid"])
def test_one_band_is_the_untiled_decode(scene, method):
    samples = encode_image(scene.right, pattern=SamplingPattern("grid", 4, 4))
    whole = decode(scene.left, samples, max_disp=16, method=method, tile_rows=0).disparity
    tiled = decode_tiled(scene.left, samples, max_disp=16, method=method, tile_rows=500, overlap=0).disparity
    np.testing.assert_array_equal(tiled, whole)


def test_bands_with_overlap_agree_with_the_untiled_decode(scene):
    samples = encode_image(scene.right, pattern=SamplingPattern("grid", 4, 4))
    whole = decode(scene.left, samples, max_disp=16, method="sparse", tile_rows=0).disparity
    tiled = decode(scene.left, samples, max_disp=16, method="sparse", tile_rows=40, tile_overlap=32).disparity
    assert tiled.shape == whole.shape
    assert np.all(np.isfinite(tiled))
    assert np.mean(np.abs(tiled - whole) > 0.5) < 0.01


def test_auto_tiling_only_when_the_frame_exceeds_the_budget(scene):
    samples = encode_image(scene.right, pattern=SamplingPattern("grid", 4, 4))
    whole = estimate_decode_memory(120, 160, 17, "sparse", stride_x=4, stride_y=4)
    assert auto_tile_rows(samples, num_disp=17, method="sparse", max_memory=whole) == 0
    band = estimate_decode_memory(64 + 2 * 16, 160, 17, "sparse", stride_x=4, stride_y=4)
    rows = auto_tile_rows(samples, num_disp=17, method="sparse", max_memory=band + 24 * 120 * 160, overlap=16)
    assert 64 <= rows < 120
    # Not even a minimal band fits: no tiling, the memory check refuses the frame instead.
    assert auto_tile_rows(samples, num_disp=17, method="sparse", max_memory=1024) == 0


def test_tiling_refuses_downsample(scene):
    samples = encode_image(scene.right, pattern=SamplingPattern("downsample", 4, 4))
    with pytest.raises(OptionError):
        decode_tiled(scene.left, samples, max_disp=16, method="downsample", tile_rows=40)


def test_bands_hold_no_large_spares_beside_their_volumes(scene, monkeypatch):
    # Bands are sized to the memory limit: their large volumes go back to the system, not
    # to the spares, so no band holds a finished one beside its own.
    from stereobudget._kernels import _scratch as scratch
    scratch.release()
    monkeypatch.setattr(scratch, "LARGE_BYTES", 16 * 1024)   # the bands' cost volumes are "large"
    monkeypatch.setattr(scratch._frames, "keepers", 0)         # a shared decoder of other tests: not ours
    monkeypatch.delenv("STEREOBUDGET_KEEP_FREED_MEMORY", raising=False)
    samples = encode_image(scene.right, pattern=SamplingPattern("grid", 4, 4))
    held = []
    recycle = scratch.recycle

    def recording_recycle(*volumes):
        recycle(*volumes)
        held.append(len(scratch._large))

    monkeypatch.setattr(scratch, "recycle", recording_recycle)
    with Decoder(keep_freed_memory=False) as decoder:       # kept between decodes, but not by bands
        tiled = decoder.decode(scene.left, samples, max_disp=16, method="sparse", tile_rows=30,
                               tile_overlap=10).disparity
        assert held and not any(held) and scratch._large == []
        whole = decoder.decode(scene.left, samples, max_disp=16, method="sparse", tile_rows=0)   # untiled: kept
        assert scratch._large
    assert scratch.spare_bytes() == 0
    np.testing.assert_array_equal(tiled, decode_tiled(scene.left, samples, max_disp=16, method="sparse",
                                                      tile_rows=30, overlap=10).disparity)
    assert whole.disparity.shape == tiled.shape


def test_the_memory_check_and_the_tiling_count_the_grid_the_params_ask_for(scene):
    # Both take the DecoderParams the decoder runs with: a finer bilateral grid needs more
    # memory, which the check before a whole-frame decode must see as the band search does.
    from stereobudget.decoding import DecoderParams, decode_memory
    from stereobudget.errors import MemoryLimitError
    samples = encode_image(scene.right, pattern=SamplingPattern("grid", 4, 4))
    fine = DecoderParams(grid_cells_per_sigma_s=2.0, grid_cells_per_sigma_r=2.0)
    coarse = decode_memory(samples, num_disp=17, method="sparse")
    needed = decode_memory(samples, num_disp=17, method="sparse", params=fine)
    assert needed > coarse
    assert needed == estimate_decode_memory(120, 160, 17, "sparse", stride_x=4, stride_y=4,
                                            cells_per_sigma_s=2.0, cells_per_sigma_r=2.0)
    decode(scene.left, samples, max_disp=16, method="sparse", max_memory=coarse, tile_rows=0)
    with pytest.raises(MemoryLimitError):
        decode(scene.left, samples, max_disp=16, method="sparse", params=fine, max_memory=needed - 1, tile_rows=0)
    decode(scene.left, samples, max_disp=16, method="sparse", params=fine, max_memory=needed, tile_rows=0)
