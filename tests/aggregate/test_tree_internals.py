"""White-box tests of stereobudget.aggregate._tree: the walk split over two threads and the
side-by-side cuts, each held to the serial walk or to the public reference (the tree's own
kernels: test_mst_internals.py).

test_tree.py holds the public calls to brute-force references; these tests pin the private
kernels the fast path is made of and go with ``_tree.py`` when it is rewritten.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereobudget.aggregate import aggregate, aggregate_two_rows_winners, build_tree, tree_layout
from stereobudget.aggregate import aggregate_reference
import stereobudget.aggregate._mst as mst_module
import stereobudget.aggregate._tree as tree_module


def random_guide(rng: np.random.Generator, height: int, width: int, levels: int = 256):
    """Random RGB uint8 image of ``levels`` grey levels spread over 0..255 (few: many tied edges)."""
    return rng.integers(0, levels, size=(height, width, 3)).astype(np.uint8) * np.uint8(255 // max(levels - 1, 1))


def smooth_tree_and_cost(shape, layers, *, seed):
    """The tree of a slightly blurred random guide and a random float32 cost volume on its grid."""
    rng = np.random.default_rng(seed)
    return (build_tree(cv2.GaussianBlur(random_guide(rng, *shape), (0, 0), 1.0)),
            rng.random(shape + (layers,), dtype=np.float32))


def test_two_thread_split_equals_the_reference():
    # The public call only splits large grids; run the split kernel directly on a small one.
    rng = np.random.default_rng(11)
    guide = random_guide(rng, 12, 13, levels=4)
    cost = rng.random((12, 13, 5), dtype=np.float32)
    tree = build_tree(guide, sigma=0.1 * 255, median_size=3)
    expected = aggregate_reference(cost, tree).reshape(-1, 5)
    out = np.empty((156, 5), np.float32)
    a0, subtree_size = mst_module._balanced_subtree(tree.order, tree.parent)
    tree_module._aggregate_two_threads(cost.reshape(-1, 5), None, tree.order, tree.parent,
                                       tree.weight, out, np.empty(0, np.float32), 0, 5, a0, subtree_size,
                                       mst_module._subtree_sizes(tree_layout(tree).parent_row))
    np.testing.assert_allclose(out, expected, rtol=1e-4)


def test_large_grid_parallel_path_matches_serial():
    rng = np.random.default_rng(12)
    guide = cv2.GaussianBlur(random_guide(rng, 140, 150), (0, 0), 2.0)
    cost = rng.random((140, 150, 20), dtype=np.float32)
    tree = build_tree(guide)
    assert tree.height * tree.width >= tree_module._PARALLEL_MIN_NODES
    serial = aggregate_reference(cost, tree)
    np.testing.assert_allclose(aggregate(cost, tree), serial, rtol=1e-5)
    in_place = cost.copy()
    aggregate(in_place, tree, out=in_place)
    np.testing.assert_allclose(in_place, serial, rtol=1e-5)
    # In place, the upward pass skips the copies of the cost (_upward_range, cost=None): same sums.
    np.testing.assert_array_equal(in_place, aggregate(cost, tree))


def _walk_inputs(case, tree, cost):
    """(cost, levels, out) of a walk: a separate cost, in place, or the refinement's levels."""
    rows = cost.reshape(tree.size, -1)
    if case == "cost":
        return rows, None, np.empty_like(rows)
    if case == "in place":
        return None, None, rows.copy()
    levels = np.where(rows[:, 0] < 0.7, rows[:, 1] * 9, np.float32(np.nan)).astype(np.float32)
    out = np.empty_like(rows)
    return out, levels, out  # as _walk passes them: the cost argument is not read


@pytest.mark.parametrize("case", ["cost", "in place", "levels"])
def test_walks_side_by_side_sum_in_the_serial_order(case):
    # Cut into ranges walked side by side, each parent still receives its children's
    # pushes in the serial walk's order: the same sums and winners, bit for bit.  Subtree
    # sizes of 1 everywhere leave nothing to cut: the plain walk.
    tree, cost = smooth_tree_and_cost((140, 150), 16, seed=31)
    sizes = mst_module._subtree_sizes(tree_layout(tree).parent_row)  # by order position
    cuts = np.empty((tree_module._MAX_CUTS, 3), np.int64)
    assert tree_module._side_by_side_cuts(sizes, 1, tree.size, cuts) >= 1
    uncut = np.ones(tree.size, np.int32)
    results = []
    for size in (uncut, tree_module._NO_SIZES, sizes):
        source, levels, out = _walk_inputs(case, tree, cost)
        winners = np.empty(tree.size, np.float32)
        tree_module._aggregate_serial(source, levels, tree.order, tree.parent, tree.weight, out, winners, -1, 16,
                                      size)
        results.append((out, winners))
    a0, subtree_size = mst_module._balanced_subtree(tree.order, tree.parent)
    for size in (uncut, sizes):
        source, levels, out = _walk_inputs(case, tree, cost)
        winners = np.empty(tree.size, np.float32)
        tree_module._aggregate_two_threads(source, levels, tree.order, tree.parent, tree.weight, out, winners, -1,
                                           16, a0, subtree_size, size)
        results.append((out, winners))
    for out, winners in results[1:3]:
        np.testing.assert_array_equal(out, results[0][0])
        np.testing.assert_array_equal(winners, results[0][1])
    np.testing.assert_array_equal(results[4][0], results[3][0])
    np.testing.assert_array_equal(results[4][1], results[3][1])
    np.testing.assert_allclose(results[3][0], results[0][0], rtol=1e-5)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_side_by_side_cuts_pair_a_whole_subtree_with_the_nodes_after_it(seed):
    tree, _ = smooth_tree_and_cost((90, 110), 1, seed=seed)
    layout = tree_layout(tree)
    sizes = mst_module._subtree_sizes(layout.parent_row)
    # Each row's subtree size, counted the slow way: every row adds one to each row on its
    # chain of parents, itself included.
    counted = np.zeros(tree.size, np.int64)
    node = np.arange(tree.size)
    while node.size:
        np.add.at(counted, node, 1)
        node = layout.parent_row[node]
        node = node[node >= 0]
    np.testing.assert_array_equal(sizes, counted)
    position = layout.row_of_pixel
    for lo, hi in ((1, tree.size), (1, tree.size // 2), (tree.size // 3, tree.size)):
        cuts = np.empty((tree_module._MAX_CUTS, 3), np.int64)
        count = tree_module._side_by_side_cuts(sizes, lo, hi, cuts)
        assert count >= 1
        end = hi
        for a0, a1, cut_end in cuts[:count]:
            assert cut_end == end and lo <= a0 < a1 <= end
            assert a1 - a0 == sizes[a0]
            # [a0, a1) is the subtree of its top node: every other member's parent lies inside.
            inside = position[tree.parent[tree.order[a0 + 1:a1]]]
            assert np.all((inside >= a0) & (inside < a1))
            assert min(a1 - a0, end - a1) >= tree_module._MIN_SIDE_BY_SIDE
            end = a0


@pytest.mark.parametrize("shape", [(12, 13), (140, 150)])  # sequential, and one walk per thread
def test_two_independent_walks_equal_the_serial_walk_of_each(shape):
    first_tree, first = smooth_tree_and_cost(shape, 6, seed=25)
    second_tree, second = smooth_tree_and_cost(shape, 6, seed=26)
    layouts = tree_layout(first_tree), tree_layout(second_tree)
    rows = [np.ascontiguousarray(c.reshape(-1, 6)[t.order]) for c, t in ((first, first_tree), (second, second_tree))]
    expected = []
    for volume, tree in ((first, first_tree), (second, second_tree)):
        serial = np.empty((tree.size, 6), np.float32)
        winners = np.empty(tree.size, np.float32)
        tree_module._aggregate_serial(volume.reshape(-1, 6), None, tree.order, tree.parent, tree.weight, serial,
                                      winners, -2, 6, tree_module._NO_SIZES)
        expected.append(winners.reshape(shape))
    got = aggregate_two_rows_winners(rows[0], layouts[0], rows[1], layouts[1], min_disp=-2)
    assert np.array_equal(got[0], expected[0]) and np.array_equal(got[1], expected[1])
    with pytest.raises(ValueError, match="rows"):
        aggregate_two_rows_winners(rows[0][:-1], layouts[0], rows[1], layouts[1], min_disp=-2)
