"""White-box tests of stereobudget.aggregate._mst: the edge keys, the counting sort, Kruskal's
steps, the fused median-and-keys kernel and the walk split the tree kernel hands its layout.

test_tree.py holds the public calls to brute-force references; these tests pin the private
kernels the tree is built of and go with ``_mst.py`` when it is rewritten.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereobudget.aggregate import MinimumSpanningTree, build_tree, build_trees, tree_layout
import stereobudget.aggregate._mst as mst_module


def random_guide(rng: np.random.Generator, height: int, width: int, levels: int = 256):
    """Random RGB uint8 image of ``levels`` grey levels spread over 0..255 (few: many tied edges)."""
    return rng.integers(0, levels, size=(height, width, 3)).astype(np.uint8) * np.uint8(255 // max(levels - 1, 1))


def _random_edge_keys(shape, dtype, *, seed, levels):
    """Edge keys of a random RGB image of ``levels`` grey levels (few: long runs of tied
    keys), in the tree kernel's uint16 with its outside key, and the grid's inner edges."""
    image = np.random.default_rng(seed).integers(0, levels, shape + (3,)).astype(dtype)
    key_count = 256 if dtype == np.uint8 else 65536
    keys = np.empty(2 * shape[0] * shape[1], np.uint16)
    mst_module._edge_keys(image, keys, 0xFFFF)
    height, width = shape
    edge_ids = np.arange(2 * height * width)
    pixel = edge_ids // 2
    inside = np.where(edge_ids % 2 == 0, pixel % width < width - 1, pixel // width < height - 1)
    return keys, key_count, inside


@pytest.mark.parametrize("shape", [(1, 1), (1, 2), (2, 1), (1, 9), (9, 1), (2, 2), (3, 5), (17, 23), (40, 31)])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_edges_are_sorted_stably_by_key(shape, dtype):
    # The 8-bit path interleaves four quarters of the edges; both must equal a stable
    # sort of the grid's edges by key (Kruskal's ties are broken by edge id).
    keys, key_count, inside = _random_edge_keys(shape, dtype, seed=sum(shape), levels=6 if dtype == np.uint8 else 3000)
    edge_ids = np.arange(keys.size)
    assert np.all(keys[~inside] == 0xFFFF) and np.all(keys[inside] < key_count)
    expected = edge_ids[inside][np.argsort(keys[inside], kind="stable")]
    got = mst_module._counting_sorted_edges(keys, edge_ids[inside].astype(np.int32), key_count)
    np.testing.assert_array_equal(got, expected)


def _block_cycle_maxima(keys, height, width):
    """Edge ids that come last, by (key, id), on some 2 x 2 block's 4-cycle (plain numpy)."""
    ids = np.arange(2 * height * width).reshape(height, width, 2)
    order = (keys.reshape(height, width, 2).astype(np.int64) << 32) | ids
    corners = [order[:-1, :-1, 0], order[:-1, :-1, 1], order[:-1, 1:, 1], order[1:, :-1, 0]]
    return np.unique(np.maximum.reduce(corners).ravel() & 0xFFFFFFFF)


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (7, 1), (2, 2), (3, 5), (17, 23), (40, 31)])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_kruskal_skips_the_block_cycle_maxima_and_keeps_its_tree(shape, dtype):
    # The edge that comes last on a 2 x 2 block's cycle is never a tree edge (the cycle
    # property), so Kruskal is given every other grid edge, in id order, and must build
    # exactly the tree it builds from all edges.
    keys, key_count, inside = _random_edge_keys(shape, dtype, seed=sum(shape) + 7,
                                                levels=4 if dtype == np.uint8 else 2000)
    height, width = shape
    inside = np.flatnonzero(inside)
    if height > 1 and width > 1:
        dropped = _block_cycle_maxima(keys, height, width)
        assert dropped.size >= (height - 1) * (width - 1) // 2
    else:
        dropped = np.zeros(0, np.int64)
    kept = mst_module._kept_edges(keys, height, width)
    np.testing.assert_array_equal(kept, np.setdiff1d(inside, dropped))
    from_kept = mst_module._counting_sorted_edges(keys, kept, key_count)
    from_all = mst_module._counting_sorted_edges(keys, inside.astype(np.int32), key_count)
    np.testing.assert_array_equal(mst_module._kruskal_tree_bits(from_kept, height, width),
                                  mst_module._kruskal_tree_bits(from_all, height, width))


def test_tree_kernel_takes_the_walk_split_and_subtree_sizes_of_its_rows():
    rng = np.random.default_rng(31)
    left = random_guide(rng, 40, 50)
    right = cv2.GaussianBlur(random_guide(rng, 40, 50), (0, 0), 1.5).astype(np.float32)
    single = tree_layout(build_tree(left))
    first, second = (tree_layout(t) for t in build_trees([left, right]))
    for layout in (single, first):
        expected = mst_module._balanced_subtree(layout.rows, layout.parent_row)
        assert layout.walk_split == tuple(int(v) for v in expected)
        # The subtree starts at that row and spans a contiguous run of rows (pre-order).
        a0, size = layout.walk_split
        assert 1 <= a0 < 2000 and 1 <= size < 2000 and a0 + size <= 2000
    assert second.walk_split is None  # the pair's second tree is walked on one thread
    for layout in (single, first):
        np.testing.assert_array_equal(layout.subtree_size, mst_module._subtree_sizes(layout.parent_row))
    assert second.subtree_size is None  # counted by the walk of the pair
    built = build_tree(left)  # the same tree made into a layout afterwards: the walk finds the split
    rebuilt = MinimumSpanningTree(order=built.order, parent=built.parent, weight=built.weight, height=40, width=50)
    assert tree_layout(rebuilt).walk_split is None and tree_layout(rebuilt).subtree_size is None


@pytest.mark.parametrize("shape", [(37, 41, 3), (1, 1, 3), (2, 9, 1), (5, 3, 4)])
def test_float_guide_median_and_keys_in_one_kernel_equal_opencv_then_keys(shape):
    rng = np.random.default_rng(31)
    image = (rng.random(shape, dtype=np.float32) * 300 - 20).astype(np.float32)   # past both ends of the keys
    image[rng.random(shape) < 0.3] = 12.5       # ties, and a value whose key rounds half to even
    expected = mst_module._uint16_keys(mst_module._median_filtered(image, 3))
    keys, non_finite = mst_module._median3_uint16_keys(image)
    np.testing.assert_array_equal(keys, expected)
    assert non_finite == 0
    image[0, 0, 0], image[-1, -1, -1] = np.nan, -np.inf
    assert mst_module._median3_uint16_keys(image)[1] == (1 if image.size == 1 else 2)
