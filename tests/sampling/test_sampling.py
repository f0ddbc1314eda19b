"""Sampling patterns: fps, adaptive_fps and downsample (grid/jitter are covered in test_container.py)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from stereobudget.io import SampleSet, read_samples, write_samples
from stereobudget.encoding import encode_image
from stereobudget.sampling import (ADAPTIVE_BASE, SamplingPattern, adaptive_split, adaptive_tile_weights,
                                   downsample_blocks, downsample_shape, fps_positions, sample_count,
                                   sample_positions, splitmix64)

GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def _tie_keys(seed: int, count: int) -> np.ndarray:
    with np.errstate(over="ignore"):
        q = np.arange(count, dtype=np.uint64)
        return splitmix64(np.uint64(seed) + (q + np.uint64(1)) * GOLDEN)


def _naive_fps(height, width, count, seed, weight_after=None):
    """Literal O(N n) transcription of the definition in docs/format.md.

    ``weight_after = (k, fn)``: from the k-th point on, the key is ``d2 * fn(rows, cols)``
    where ``fn`` gets the first k points and returns a per-pixel weight.
    """
    q = np.arange(height * width)
    yy, xx = np.divmod(q, width)
    tie = _tie_keys(seed, height * width)
    d2 = np.full(height * width, np.iinfo(np.int64).max // 4, dtype=np.int64)
    weight = np.ones(height * width, dtype=np.int64)
    chosen = []
    for k in range(count):
        if weight_after is not None and k == weight_after[0]:
            pts = np.array(chosen)
            weight = weight_after[1](pts[:, 0], pts[:, 1])
        key = d2 * weight
        candidates = np.flatnonzero(key == key.max())
        p = int(candidates[np.argmax(tie[candidates])])
        chosen.append(divmod(p, width))
        d2 = np.minimum(d2, (yy - chosen[-1][0]) ** 2 + (xx - chosen[-1][1]) ** 2)
    return np.array(chosen, dtype=np.int64).reshape(-1, 2)


@pytest.mark.parametrize("height, width, stride, seed", [
    (23, 37, 3, 0), (40, 17, 2, 7), (9, 9, 1, 2 ** 64 - 1), (50, 61, 5, 12345), (1, 13, 2, 3)])
def test_fps_matches_the_literal_definition(height, width, stride, seed):
    pattern = SamplingPattern("fps", stride, stride, seed=seed)
    rows, cols = sample_positions(pattern, height, width)
    expected = _naive_fps(height, width, sample_count(pattern, height, width), seed)
    np.testing.assert_array_equal(rows, expected[:, 0])
    np.testing.assert_array_equal(cols, expected[:, 1])


def test_fps_is_deterministic_distinct_and_exact_in_count():
    h, w = 97, 131
    pattern = SamplingPattern("fps", 4, 4, seed=99)
    rows, cols = sample_positions(pattern, h, w)
    rows2, cols2 = sample_positions(SamplingPattern("fps", 4, 4, seed=99), h, w)
    np.testing.assert_array_equal(rows, rows2)
    np.testing.assert_array_equal(cols, cols2)
    assert len(rows) == sample_count(pattern, h, w) == 25 * 33
    assert len(set(zip(rows.tolist(), cols.tolist()))) == len(rows)
    assert rows.min() >= 0 and rows.max() < h and cols.min() >= 0 and cols.max() < w
    other, _ = sample_positions(SamplingPattern("fps", 4, 4, seed=100), h, w)
    assert not np.array_equal(rows, other)


def test_fps_with_stride_one_takes_every_pixel():
    rows, cols = fps_positions(7, 11, 77, seed=5)
    assert sorted(zip(rows.tolist(), cols.tolist())) == [(y, x) for y in range(7) for x in range(11)]


def _nearest_neighbour_distances(rows, cols):
    pts = np.stack([rows, cols], axis=1).astype(np.float64)
    d = np.sqrt(((pts[:, None, :] - pts[None, :, :]) ** 2).sum(axis=2))
    np.fill_diagonal(d, np.inf)
    return d.min(axis=1)


def test_fps_is_roughly_uniform():
    """FPS keeps a minimum spacing close to the grid's and covers the image as well as it."""
    h, w, s = 120, 150, 5
    rows, cols = sample_positions(SamplingPattern("fps", s, s, seed=1), h, w)
    nn = _nearest_neighbour_distances(rows, cols)
    # Every point was at least as far as the covering radius at its time; the packing
    # argument bounds it below by about 0.8 of the grid spacing.
    assert nn.min() >= 0.75 * s
    # Covering radius: no pixel is far from a sample (the grid's is s / sqrt(2) = 3.5).
    yy, xx = np.mgrid[0:h, 0:w]
    d2 = np.full((h, w), np.inf)
    for r, c in zip(rows, cols):
        np.minimum(d2, (yy - r) ** 2 + (xx - c) ** 2, out=d2)
    assert np.sqrt(d2.max()) <= 1.2 * s
    # Density is even: each quarter of the image gets a quarter of the samples (+-10 %).
    quarters = np.bincount((rows >= h // 2) * 2 + (cols >= w // 2), minlength=4)
    assert np.all(np.abs(quarters - len(rows) / 4) <= 0.1 * len(rows) / 4)


def test_fps_on_teddy_sized_images_is_fast():
    fps_positions(40, 40, 64, seed=0)  # compile / load the cache outside the timing
    start = time.perf_counter()
    rows, _ = sample_positions(SamplingPattern("fps", 5, 5, seed=3), 375, 450)
    assert len(rows) == 6750
    assert time.perf_counter() - start < 1.0


def _textured_image(h, w, seed=0, dtype=np.uint8):
    rng = np.random.default_rng(seed)
    peak = 255 if dtype == np.uint8 else 65535
    img = np.full((h, w, 3), peak // 2, dtype=dtype)
    # Left half flat, right half noisy: adaptive samples must prefer the right half.
    img[:, w // 2:] = rng.integers(0, peak + 1, size=(h, w - w // 2, 3), dtype=dtype)
    return img


@pytest.mark.parametrize("height, width, stride", [(23, 37, 3), (50, 61, 5), (31, 30, 2)])
def test_adaptive_fps_matches_the_literal_definition(height, width, stride):
    img = _textured_image(height, width, seed=stride)
    pattern = SamplingPattern("adaptive_fps", stride, stride, seed=3)
    n = sample_count(pattern, height, width)
    uniform, adaptive = adaptive_split(n)
    assert adaptive == n // 5 and uniform + adaptive == n

    def per_pixel_weight(rows, cols):
        tiles = adaptive_tile_weights(rows, cols, img[rows, cols], height=height, width=width,
                                      tile_h=stride, tile_w=stride)
        yy, xx = np.divmod(np.arange(height * width), width)
        return tiles[yy // stride, xx // stride]

    expected = _naive_fps(height, width, n, 3, weight_after=(uniform, per_pixel_weight))
    rows, cols = sample_positions(pattern, height, width, image=img)
    np.testing.assert_array_equal(rows, expected[:, 0])
    np.testing.assert_array_equal(cols, expected[:, 1])
    # The first 80 % are plain FPS.
    plain_rows, plain_cols = fps_positions(height, width, uniform, seed=3)
    np.testing.assert_array_equal(rows[:uniform], plain_rows)
    np.testing.assert_array_equal(cols[:uniform], plain_cols)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_adaptive_fps_decoder_regenerates_the_encoder_positions(dtype):
    h, w = 90, 120
    img = _textured_image(h, w, seed=4, dtype=dtype)
    pattern = SamplingPattern("adaptive_fps", 4, 4, seed=11)
    encoded = encode_image(img, pattern=pattern)
    rows_enc, cols_enc = sample_positions(pattern, h, w, image=img)
    np.testing.assert_array_equal(encoded.values, img[rows_enc, cols_enc])
    decoded = read_samples(write_samples(encoded))
    rows_dec, cols_dec = decoded.positions()
    np.testing.assert_array_equal(rows_dec, rows_enc)
    np.testing.assert_array_equal(cols_dec, cols_enc)
    # Content adaptivity: most adaptive samples land in the textured half.
    uniform, _ = adaptive_split(len(rows_enc))
    assert np.mean(cols_enc[uniform:] >= w // 2) > 0.8
    # Without values the decoder cannot know the positions.
    with pytest.raises(ValueError, match="values"):
        sample_positions(pattern, h, w)


def test_adaptive_tile_weights_follow_the_definition():
    rows = np.array([0, 0, 9, 5])
    cols = np.array([0, 9, 0, 5])
    values = np.array([[10, 0, 0], [200, 0, 0], [10, 0, 0], [10, 0, 50]], dtype=np.uint8)
    weights = adaptive_tile_weights(rows, cols, values, height=10, width=10, tile_h=3, tile_w=3)
    assert weights.shape == (4, 4)
    # Tile (0, 2) sees the samples of tiles (0..1, 1..3): (0, 9) -> 200 and (5, 5) -> 10 / 50.
    assert weights[0, 2] == ADAPTIVE_BASE + 190
    # Tile (3, 0) sees only (9, 0): range 0.
    assert weights[3, 0] == ADAPTIVE_BASE
    # Tile (2, 1) sees (5, 5) and (9, 0): channel 2 spans 0..50, channel 0 spans 10..10.
    assert weights[2, 1] == ADAPTIVE_BASE + 50
    # uint16 values count in 8-bit units (high byte).
    w16 = adaptive_tile_weights(rows, cols, values.astype(np.uint16) * 257, height=10, width=10,
                                tile_h=3, tile_w=3)
    np.testing.assert_array_equal(w16, weights)


@pytest.mark.parametrize("shape, sx, sy", [((37, 53, 3), 5, 5), ((12, 12), 4, 4), ((10, 23, 1), 3, 7),
                                           ((8, 9, 3), 1, 1)])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_downsample_blocks_are_exact_rounded_means(shape, sx, sy, dtype):
    rng = np.random.default_rng(sum(shape) + sx)
    img = rng.integers(0, np.iinfo(dtype).max + 1, size=shape, dtype=dtype)
    pattern = SamplingPattern("downsample", sx, sy)
    blocks = downsample_blocks(img, pattern)
    img3 = img if img.ndim == 3 else img[:, :, None]
    h, w, c = img3.shape
    rows, cols = downsample_shape(pattern, h, w)
    assert blocks.shape == (rows * cols, c) == (sample_count(pattern, h, w), c)
    assert blocks.dtype == dtype
    expected = np.empty((rows, cols, c), dtype=np.int64)
    for by in range(rows):
        for bx in range(cols):
            cell = img3[by * sy:(by + 1) * sy, bx * sx:(bx + 1) * sx].reshape(-1, c).astype(np.float64)
            expected[by, bx] = np.floor(cell.mean(axis=0) + 0.5)
    np.testing.assert_array_equal(blocks.reshape(rows, cols, c), expected)


def test_downsample_positions_are_block_centres():
    pattern = SamplingPattern("downsample", 4, 3)
    rows, cols = sample_positions(pattern, 7, 10)
    # Blocks: rows [0,3) [3,6) [6,7); cols [0,4) [4,8) [8,10).
    np.testing.assert_array_equal(rows, [1, 1, 1, 4, 4, 4, 6, 6, 6])
    np.testing.assert_array_equal(cols, [1, 5, 8, 1, 5, 8, 1, 5, 8])


@pytest.mark.parametrize("kind", ["grid", "jitter", "fps", "adaptive_fps", "downsample"])
@pytest.mark.parametrize("dtype, order", [(np.uint8, "rgb"), (np.uint16, "bgr"), (np.uint8, "gray")])
def test_every_pattern_round_trips_through_the_sample_file(kind, dtype, order):
    h, w = 41, 57
    img = _textured_image(h, w, seed=2, dtype=dtype)
    if order == "gray":
        img = img[:, :, 0]
    pattern = SamplingPattern(kind, 3, 4, seed=0 if kind == "grid" else 77)
    original = encode_image(img, pattern=pattern, channel_order=order)
    restored = read_samples(write_samples(original))
    assert isinstance(restored, SampleSet)
    assert restored.pattern == pattern
    assert restored.channel_order == order
    assert restored.values.dtype == dtype
    np.testing.assert_array_equal(restored.values, original.values)
    rows, cols = restored.positions()
    rows0, cols0 = original.positions()
    np.testing.assert_array_equal(rows, rows0)
    np.testing.assert_array_equal(cols, cols0)
    img3 = img if img.ndim == 3 else img[:, :, None]
    if kind == "downsample":
        np.testing.assert_array_equal(restored.values, downsample_blocks(img3, pattern))
    else:
        np.testing.assert_array_equal(restored.values, img3[rows, cols])


def test_test_vectors_of_docs_format_md():
    rows, cols = sample_positions(SamplingPattern("fps", 4, 4, seed=42), 6, 10)
    assert list(zip(rows.tolist(), cols.tolist())) == [(4, 9), (0, 0), (5, 3), (0, 5), (0, 9), (4, 0)]
    rows, cols = sample_positions(SamplingPattern("fps", 5, 5, seed=0), 375, 450)
    assert list(zip(rows[:5].tolist(), cols[:5].tolist())) == [(322, 225), (0, 0), (0, 449), (240, 0),
                                                               (83, 224)]
    y, x = np.mgrid[0:12, 0:16]
    img = np.where(x < 8, 100, (37 * (16 * y + x)) % 256).astype(np.uint8)
    rows, cols = sample_positions(SamplingPattern("adaptive_fps", 4, 4, seed=42), 12, 16, image=img)
    assert list(zip(rows.tolist(), cols.tolist())) == [
        (7, 7), (0, 15), (0, 0), (11, 15), (11, 0), (0, 7), (6, 13), (5, 2), (11, 10), (2, 11), (11, 5), (5, 10)]
    img = np.arange(35, dtype=np.uint8).reshape(5, 7)
    np.testing.assert_array_equal(downsample_blocks(img, SamplingPattern("downsample", 3, 2)).ravel(),
                                  [5, 8, 10, 19, 22, 24, 29, 32, 34])


@pytest.mark.parametrize("kind", ["fps", "adaptive_fps", "downsample"])
def test_sb_encode_writes_the_new_patterns(tmp_path, kind):
    import cv2
    from click.testing import CliRunner

    from stereobudget.cli.encode import encode_command
    from stereobudget.io import load_samples

    img = _textured_image(30, 44, seed=8)
    cv2.imwrite(str(tmp_path / "right.png"), img[:, :, ::-1])
    args = [str(tmp_path / "right.png"), "-o", str(tmp_path / "r.sbs"), "--pattern", kind, "--stride", "3"]
    if kind != "downsample":
        args += ["--seed", "21"]
    result = CliRunner().invoke(encode_command, args)
    assert result.exit_code == 0, result.output
    samples = load_samples(tmp_path / "r.sbs")
    assert samples.pattern == SamplingPattern(kind, 3, 3, seed=0 if kind == "downsample" else 21)
    assert samples.channel_order == "rgb"
    if kind == "downsample":
        np.testing.assert_array_equal(samples.values, downsample_blocks(img, samples.pattern))
    else:
        rows, cols = samples.positions()
        np.testing.assert_array_equal(samples.values, img[rows, cols])
