"""White-box tests of stereobudget.fill._bilateral: the stride-periodic weight grids, the lattice
splat in row parts, the splat of any pattern row by row and the three-pass grid blur, each
bit-identical to the plain per-sample or per-layer computation.
"""

import numpy as np
import pytest
from numba import njit

from stereobudget.cost import SparseCostTerms
from stereobudget.fill import FillScale
from stereobudget.fill import _bilateral as bilateral
from stereobudget.fill import _grid as grid
from stereobudget.encoding import encode_image
from stereobudget.cost import sample_row_steps, to_float_image, to_gray
from stereobudget.sampling import SamplingPattern, grid_shape
from stereobudget.scenes import make_scene


@pytest.fixture(scope="module")
def scene():
    return make_scene("slanted", height=72, width=150, max_disp=24, seed=2)


def _inputs(scene, pattern):
    samples = encode_image(scene.right, pattern=pattern)
    rows, cols = samples.positions()
    values = to_float_image(samples.values_rgb()[:, None, :])[:, 0, :]
    left = to_float_image(scene.left)
    return left, to_gray(left), rows, cols, values, samples


def _force_parts(monkeypatch, parts):
    """Have the row splats cut their sample rows into ``parts`` parts; returns the list of the counts they took."""
    chosen = []
    lattice_parts = bilateral._lattice_parts

    def parts_of(sample_rows, inv_cs, gy, _threads):
        bounds, shared, zeroed = lattice_parts(sample_rows, inv_cs, gy, parts)
        chosen.append(len(bounds) - 1)
        return bounds, shared, zeroed

    monkeypatch.setattr(bilateral, "_lattice_parts", parts_of)
    return chosen


def _splat_per_sample(rows, cols, samples, pixels, min_disp, cost_terms, geom, grid_val, grid_w):
    """The general route's splat as the per-sample kernel (the samples must come sorted)."""
    bilateral._splat_sparse_dsi_split(rows, cols, samples, pixels, min_disp, cost_terms, bilateral._grid_scales(geom),
                                      grid_val, grid_w)


@pytest.mark.parametrize("stride, offset_x, offset_y, min_disp, num_disp, steps", [
    (5, 0, 0, 0, 25, True), (4, 3, 1, 0, 25, False), (3, 1, 2, 6, 19, True), (6, 5, 0, 2, 13, False),
    (17, 2, 0, 0, 40, False)])  # more base channels than the vector slice takes: summed, then tiled
def test_split_weights_are_bit_identical(scene, monkeypatch, stride, offset_x, offset_y, min_disp, num_disp, steps):
    pattern = SamplingPattern("grid", stride, stride, offset_x, offset_y)
    left, guide, rows, cols, values, samples = _inputs(scene, pattern)
    kwargs = dict(min_disp=min_disp, num_disp=num_disp, scale=FillScale(sigma_s=2.0 * stride, sigma_r=15.0),
                  terms=SparseCostTerms(truncation=15.0))
    if steps:
        lattice = to_gray(values.reshape(grid_shape(pattern, samples.height, samples.width) + (-1,)))
        kwargs.update(right_steps=sample_row_steps(lattice).ravel(),
                      terms=SparseCostTerms(truncation=15.0, step_spacing=stride, step_weight=0.4))
    assert bilateral._lattice_stride(np.asarray(rows, np.int64), np.asarray(cols, np.int64), 150) == stride
    split = bilateral.filled_sparse_dsi(left, guide, rows, cols, values, **kwargs)
    monkeypatch.setattr(bilateral, "_lattice_stride", lambda *args: 0)
    monkeypatch.setattr(bilateral, "_splat_any_pattern", _splat_per_sample)
    per_layer = bilateral.filled_sparse_dsi(left, guide, rows, cols, values, **kwargs)
    np.testing.assert_array_equal(split, per_layer)


@pytest.mark.parametrize("stride, offset_x, min_disp, num_disp", [(5, 0, 0, 120), (3, 2, 4, 100), (4, 1, 0, 140)])
def test_layers_out_of_reach_are_written_as_missing_bit_identically(scene, monkeypatch, stride, offset_x, min_disp,
                                                                      num_disp):
    # A search range close to the width: left of x = d the layers have no sample, and the
    # lattice path skips their slice where the band's weights are surely zero.
    pattern = SamplingPattern("grid", stride, stride, offset_x, 1)
    left, guide, rows, cols, values, _ = _inputs(scene, pattern)
    kwargs = dict(min_disp=min_disp, num_disp=num_disp, scale=FillScale(sigma_s=2.0 * stride, sigma_r=15.0),
                  terms=SparseCostTerms(truncation=15.0))
    grids = bilateral.sparse_dsi_grids(left, guide, rows, cols, values, **kwargs)
    skipped = grids.first_missing_layer < num_disp
    assert skipped.any()
    assert np.all(grids.first_missing_layer >= grids.first_band_layer)
    split = bilateral.filled_sparse_dsi(left, guide, rows, cols, values, **kwargs)
    x_cell = np.minimum(np.floor(np.arange(150) * grids.inv_cell_s), grids.gx - 2).astype(int)
    first_missing = grids.first_missing_layer[x_cell]
    layer = np.arange(num_disp)
    assert np.all(split[:, layer[None, :] >= first_missing[:, None]] == np.float32(15.0))
    monkeypatch.setattr(bilateral, "_lattice_stride", lambda *args: 0)
    monkeypatch.setattr(bilateral, "_splat_any_pattern", _splat_per_sample)
    per_layer = bilateral.filled_sparse_dsi(left, guide, rows, cols, values, **kwargs)
    np.testing.assert_array_equal(split, per_layer)


@njit(cache=True)
def _slice_by_layer(grids, guide, out, light):
    """The fill stated layer by layer: each layer's values over its weight, or where that
    weight is light (<= eps) the spatial-only fallback; ``light`` counts the light layers
    below and from the band's first layer."""
    h, w = guide.shape
    n_out = out.shape[2]
    den, corner_index, band_index, corner_weight = grid.slice_scratch(n_out)
    for y in range(h):
        for x in range(w):
            o = out[y, x]
            y0, ty = grid._hat(y * grids.inv_cell_s, grids.gy)
            x0, tx = grid._hat(x * grids.inv_cell_s, grids.gx)
            z0, tz = grid._hat(guide[y, x] * grids.inv_cell_r, grids.gz)
            n = min(grids.first_missing_layer[x0], n_out)
            grid._trilinear_corners(y0, ty, x0, tx, z0, tz, grids.gx, grids.gz, corner_weight, corner_index)
            grid._add_corners_from(grids.values, corner_index, corner_weight, 0, n, o)
            start = grids.first_band_layer[x0]
            grid._layer_weights(grids.base_weights, corner_index, corner_weight, min(start, n), den, grids.eps)
            if start < n:
                grid._trilinear_corners(y0, ty, x0, tx, z0, tz, grids.band, grids.gz, corner_weight,
                                             band_index)
                grid._add_corners_from(grids.band_weights, band_index, corner_weight, start, n, den)
            for i in range(n):
                if den[i] > grids.eps:
                    o[i] = o[i] / den[i]
                    continue
                light[0 if i < start else 1] += 1
                sv = grid._bilinear(grids.spatial_values, y0, ty, x0, tx, i)
                if i >= start:
                    sw = grid._bilinear(grids.spatial_band, y0, ty, x0, tx, i)
                else:
                    sw = grid._bilinear(grids.spatial_base, y0, ty, x0, tx, grids.layer_base[i])
                o[i] = sv / sw if sw > grids.eps else grids.missing_value
            for i in range(n, n_out):
                o[i] = grids.missing_value


@pytest.mark.parametrize("stride, offset_x, min_disp, num_disp", [(5, 0, 0, 64), (3, 2, 4, 40), (4, 1, 0, 100)])
def test_light_layers_take_the_spatial_fallback_layer_by_layer(scene, stride, offset_x, min_disp, num_disp):
    # The slice divides every layer and then redoes the light ones (a run near the left
    # border, the rare base layer); the result must be the per-layer definition's, bit for bit.
    pattern = SamplingPattern("grid", stride, stride, offset_x, 1)
    left, guide, rows, cols, values, _ = _inputs(scene, pattern)
    guide = guide.copy()
    # Bright dots off the lattice rows: no sample shares their intensity, so every layer
    # of theirs, base or band, is light.
    guide[2::stride, 60::23] = 255.0
    grids = bilateral.sparse_dsi_grids(left, guide, rows, cols, values, min_disp=min_disp, num_disp=num_disp,
                                       scale=FillScale(sigma_s=2.0 * stride, sigma_r=15.0),
                                       terms=SparseCostTerms(truncation=15.0))
    expected = np.empty((72, 150, num_disp), np.float32)
    light = np.zeros(2, np.int64)
    _slice_by_layer(grids, guide, expected, light)
    assert light[0] > 0 and light[1] > 0
    np.testing.assert_array_equal(grid.slice_volume(guide, grids), expected)


def test_lattice_detection_rejects_other_layouts(scene):
    _, _, rows, cols, _, _ = _inputs(scene, SamplingPattern("jitter", 4, 4, seed=1))
    assert bilateral._lattice_stride(np.asarray(rows, np.int64), np.asarray(cols, np.int64), 150) == 0
    _, _, rows, cols, _, _ = _inputs(scene, SamplingPattern("grid", 4, 4))
    rows, cols = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
    assert bilateral._lattice_stride(rows[::-1], cols[::-1], 150) == 0      # not row-major
    assert bilateral._lattice_stride(rows[:-1], cols[:-1], 150) == 0        # a sample missing
    keep = cols < 100
    assert bilateral._lattice_stride(rows[keep], cols[keep], 150) == 0      # stops short of the edge


@pytest.mark.parametrize("pattern", [SamplingPattern("grid", 5, 5), SamplingPattern("jitter", 4, 4, seed=3)])
def test_fill_written_in_any_row_order_holds_the_same_rows(scene, pattern):
    # The decoders have the fill write its volume in a tree's depth-first order
    # (``pixel_of_row``); every row must be bit-identical to that pixel's row in pixel order.
    left, guide, rows, cols, values, _ = _inputs(scene, pattern)
    kwargs = dict(min_disp=0, num_disp=20, scale=FillScale(sigma_s=10.0, sigma_r=15.0),
                  terms=SparseCostTerms(truncation=15.0))
    in_pixel_order = bilateral.filled_sparse_dsi(left, guide, rows, cols, values, **kwargs)
    pixel_of_row = np.random.default_rng(5).permutation(72 * 150)
    in_rows = bilateral.filled_sparse_dsi(left, guide, rows, cols, values, pixel_of_row=pixel_of_row, **kwargs)
    assert in_rows.shape == (72 * 150, 20)
    np.testing.assert_array_equal(in_rows, in_pixel_order.reshape(-1, 20)[pixel_of_row])


def _lattice_stride_by_sets(rows, cols, width):
    """The lattice test stated with numpy's sets: row-major, evenly spaced columns from
    ``ox < s`` to the right edge, every (row, column) present once."""
    if len(rows) < 2 or not np.all(np.diff(rows * width + cols) > 0):
        return 0
    columns = np.unique(cols)
    if len(columns) < 2:
        return 0
    stride = int(columns[1] - columns[0])
    if stride < 1 or columns[0] >= stride or columns[-1] + stride < width or not np.all(np.diff(columns) == stride):
        return 0
    return stride if len(rows) == len(np.unique(rows)) * len(columns) else 0


def test_lattice_detection_agrees_with_the_set_definition():
    rng = np.random.default_rng(11)
    width = 40
    for trial in range(400):
        stride = int(rng.integers(1, 7))
        ox = int(rng.integers(0, stride + 1))                    # ox == stride: not a lattice
        cols_row = np.arange(ox, width, stride)
        row_ids = np.sort(rng.choice(30, size=int(rng.integers(1, 6)), replace=False))
        rows = np.repeat(row_ids, len(cols_row)).astype(np.int64)
        cols = np.tile(cols_row, len(row_ids)).astype(np.int64)
        kind = trial % 6
        if kind == 1 and len(rows) > 1:                          # one sample dropped
            keep = np.ones(len(rows), bool)
            keep[rng.integers(len(rows))] = False
            rows, cols = rows[keep], cols[keep]
        elif kind == 2 and len(rows) > 1:                        # one column moved
            cols = cols.copy()
            cols[rng.integers(len(cols))] += 1
        elif kind == 3:                                          # a row repeated
            rows = np.concatenate([rows, rows[-len(cols_row):]])
            cols = np.concatenate([cols, cols[-len(cols_row):]])
        elif kind == 4:                                          # stops short of the right edge
            keep = cols < width - stride - 1
            rows, cols = rows[keep], cols[keep]
        expected = _lattice_stride_by_sets(rows, cols, width)
        assert bilateral._lattice_stride(rows, cols, width) == expected, (trial, stride, ox, kind)


@pytest.mark.parametrize("parts", [1, 2, 3, 4])
def test_lattice_splat_in_row_parts_is_bit_identical(scene, monkeypatch, parts):
    # Threads splat contiguous parts of the sample rows; the grid cells where two parts
    # meet are added after the part above, so every sum keeps the single pass's order.
    # 72 rows at stride 3 with sigma_s 6 (3 px cells): 24 sample rows over 25 cell rows.
    stride = 3
    pattern = SamplingPattern("grid", stride, stride, 1, 2)
    left, guide, rows, cols, values, samples = _inputs(scene, pattern)
    lattice = to_gray(values.reshape(grid_shape(pattern, samples.height, samples.width) + (-1,)))
    kwargs = dict(min_disp=1, num_disp=16, right_steps=sample_row_steps(lattice).ravel(),
                  scale=FillScale(sigma_s=2.0 * stride, sigma_r=15.0, cells_per_sigma_s=2.0, cells_per_sigma_r=1.0),
                  terms=SparseCostTerms(truncation=15.0, step_spacing=stride, step_weight=0.4))
    chosen = _force_parts(monkeypatch, parts)
    # The lattice path zeroes its grids itself: hand it garbage to prove it.
    monkeypatch.setattr(bilateral, "empty_volume", lambda shape: np.full(shape, np.nan, np.float32))
    split = bilateral.filled_sparse_dsi(left, guide, rows, cols, values, **kwargs)
    assert chosen == [parts]
    monkeypatch.setattr(bilateral, "_lattice_stride", lambda *args: 0)
    monkeypatch.setattr(bilateral, "_splat_any_pattern", _splat_per_sample)
    per_sample = bilateral.filled_sparse_dsi(left, guide, rows, cols, values, **kwargs)
    np.testing.assert_array_equal(split, per_sample)



@pytest.mark.parametrize("parts", [1, 2, 3])
@pytest.mark.parametrize("min_disp, subpixel", [(0, True), (-3, False), (2, True)])
def test_any_pattern_splat_row_by_row_is_bit_identical(scene, monkeypatch, parts, min_disp, subpixel):
    # Samples off any lattice (jittered, one pixel sampled twice, in no order, with the
    # sub-pixel offsets of a grid placed in a rectified frame) are splatted row by row in
    # parts; every sum must keep the per-sample kernel's order over the sorted samples.
    left, guide, rows, cols, values, _ = _inputs(scene, SamplingPattern("jitter", 4, 4, seed=3))
    rng = np.random.default_rng(parts)
    rows = np.append(np.asarray(rows, np.int64), rows[40])
    cols = np.append(np.asarray(cols, np.int64), cols[40])
    values = np.concatenate([values, values[:1] + 9.0])
    n = len(rows)
    right = dict(right_steps=rng.uniform(-20, 20, n).astype(np.float32),
                 right_codes=rng.integers(0, 255, n).astype(np.int64),
                 right_offsets=rng.uniform(-0.5, 0.5, (n, 2)).astype(np.float32) if subpixel else None)
    kwargs = dict(min_disp=min_disp, num_disp=17, scale=FillScale(sigma_s=6.0, sigma_r=15.0, cells_per_sigma_r=1.0),
                  terms=SparseCostTerms(truncation=15.0, step_spacing=4, step_weight=0.4, census_weight=0.3,
                                        census_spacing=(4, 4)))
    shuffled = rng.permutation(n)
    chosen = _force_parts(monkeypatch, parts)
    by_rows = bilateral.filled_sparse_dsi(left, guide, rows[shuffled], cols[shuffled], values[shuffled],
                                          **{k: v[shuffled] if v is not None else None for k, v in right.items()},
                                          **kwargs)
    assert chosen == [parts]
    monkeypatch.setattr(bilateral, "_splat_any_pattern", _splat_per_sample)
    # Sorted as the fill sorts (stable: the pixel sampled twice keeps its shuffled order).
    order = shuffled[np.lexsort((cols[shuffled], rows[shuffled]))]
    per_sample = bilateral.filled_sparse_dsi(left, guide, rows[order], cols[order], values[order],
                                             **{k: v[order] if v is not None else None for k, v in right.items()},
                                             **kwargs)
    np.testing.assert_array_equal(by_rows, per_sample)


def test_lattice_parts_keep_shared_cells_between_neighbours():
    sample_rows = np.arange(2, 72, 5, dtype=np.int64)         # 14 rows, cells of 10 px
    cells = np.minimum(np.floor(sample_rows * 0.1).astype(int), 7)
    for parts in (2, 3, 4, 8):
        bounds, shared, zeroed = bilateral._lattice_parts(sample_rows, 0.1, 9, parts)
        assert bounds[0] == 0 and bounds[-1] == len(sample_rows) and np.all(np.diff(bounds) >= 2)
        for p in range(1, len(bounds) - 2):                    # a part never reaches two parts up
            assert cells[bounds[p + 1]] > cells[bounds[p] - 1] + 1
        # Each part shares the cells the part above reaches: up to its last row's cell + 1.
        assert shared[0] == -1 and list(shared[1:]) == [cells[b - 1] + 1 for b in bounds[1:-1]]
        # Every row of cells is zeroed by exactly one part, the one whose first loop writes it.
        assert list(zeroed) == [0] + [s + 1 for s in shared[1:]] + [9]
    bounds, shared, zeroed = bilateral._lattice_parts(sample_rows[:3], 0.1, 9, 2)
    assert list(bounds) == [0, 3] and list(shared) == [-1] and list(zeroed) == [0, 9]  # too short to split


def test_base_weights_end_in_zero_cells_and_are_reused_by_the_next_fill(scene):
    # The slice's vector loads read past the last cell's channels: the grid carries zero
    # cells for them, and is handed back whole, so the next fill of the frame takes it again.
    from stereobudget._kernels import _scratch
    _scratch.release()                                        # no spares of earlier tests to take instead
    pattern = SamplingPattern("grid", 5, 5, 0, 0)
    left, guide, rows, cols, values, _ = _inputs(scene, pattern)
    kwargs = dict(min_disp=0, num_disp=25, scale=FillScale(sigma_s=10.0, sigma_r=15.0),
                  terms=SparseCostTerms(truncation=15.0))
    grids = bilateral.sparse_dsi_grids(left, guide, rows, cols, values, **kwargs)
    cells = grids.gy * grids.gx * grids.gz
    channels = grids.base_weights.shape[1]
    assert channels == 5
    assert (grids.base_weights.shape[0] - cells) * channels >= grid.PERIOD_READ_PAST
    assert np.all(grids.base_weights[cells:] == 0)
    address = grids.base_weights.ctypes.data
    with _scratch.in_use():                                   # as within a decode
        grid.release_grids(grids)
        again = bilateral.sparse_dsi_grids(left, guide, rows, cols, values, **kwargs)
        assert again.base_weights.ctypes.data == address
        grid.release_grids(again)
    assert _scratch.spare_bytes() == 0 or _scratch.keeping()
