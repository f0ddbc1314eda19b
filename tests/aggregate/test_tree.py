"""The public tree calls of stereobudget.aggregate: the MST of the guide grid and non-local aggregation on it.

References here are deliberately naive pure Python (Prim with a heap, O(N^2) path
products) and run on tiny images only.
"""

from __future__ import annotations

import heapq
import math
from collections import deque

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stereobudget.errors import ImageReadError, OptionError
from stereobudget.aggregate import (MinimumSpanningTree, aggregate, aggregate_rows_winners, aggregate_two_rows_winners,
                               aggregate_winners, build_trees, build_tree, distance_rows_winners, tree_layout)
from stereobudget.aggregate import aggregate_reference, winner_take_all

SIGMA = 0.1 * 255


# --------------------------------------------------------------------------------------
# Naive references


def grid_edge_weights(guide: np.ndarray, median_size: int) -> dict[tuple[int, int], float]:
    """{(p, q): max abs channel difference in 8-bit units} for every 4-neighbour pair p < q."""
    image = guide if guide.ndim == 3 else guide[:, :, None]
    if median_size > 1:
        filtered = [cv2.medianBlur(np.ascontiguousarray(image[:, :, c]), median_size) for c in range(image.shape[2])]
        image = np.stack(filtered, axis=2)
    scale = 1.0 / 257.0 if image.dtype == np.uint16 else 1.0
    values = image.astype(np.float64) * scale
    height, width = image.shape[:2]
    weights = {}
    for r in range(height):
        for c in range(width):
            p = r * width + c
            if c + 1 < width:
                weights[(p, p + 1)] = float(np.max(np.abs(values[r, c] - values[r, c + 1])))
            if r + 1 < height:
                weights[(p, p + width)] = float(np.max(np.abs(values[r, c] - values[r + 1, c])))
    return weights


def prim_minimum_weight(node_count: int, weights: dict[tuple[int, int], float]) -> float:
    """Total weight of a minimum spanning tree by Prim's algorithm (independent of Kruskal)."""
    neighbours: dict[int, list[tuple[float, int]]] = {p: [] for p in range(node_count)}
    for (p, q), w in weights.items():
        neighbours[p].append((w, q))
        neighbours[q].append((w, p))
    in_tree = [False] * node_count
    heap = [(0.0, 0)]
    total = 0.0
    while heap:
        w, p = heapq.heappop(heap)
        if in_tree[p]:
            continue
        in_tree[p] = True
        total += w
        for edge in neighbours[p]:
            if not in_tree[edge[1]]:
                heapq.heappush(heap, edge)
    assert all(in_tree)
    return total


def tree_edges(tree: MinimumSpanningTree) -> list[tuple[int, int]]:
    return [tuple(sorted((int(v), int(p)))) for v, p in enumerate(tree.parent) if p >= 0]


def tree_distance_similarity_bruteforce(guide: np.ndarray, *, sigma: float, median_size: int):
    """Similarity matrix S (N, N) of the tree build_tree picks, by walking every path in Python.

    The tree's *edges* come from build_tree (ties make the MST non-unique, so no other tree
    can be compared), but the edge similarities are recomputed here from the guide and the
    path products are taken pair by pair.  Returns (S, tree).
    """
    tree = build_tree(guide, sigma=sigma, median_size=median_size)
    weights = grid_edge_weights(guide, median_size)
    node_count = tree.height * tree.width
    adjacency: dict[int, list[tuple[int, float]]] = {p: [] for p in range(node_count)}
    for p, q in tree_edges(tree):
        similarity = math.exp(-weights[(p, q)] / sigma)
        adjacency[p].append((q, similarity))
        adjacency[q].append((p, similarity))
    similarity_matrix = np.zeros((node_count, node_count))
    for source in range(node_count):
        similarity_matrix[source, source] = 1.0
        queue = deque([source])
        while queue:
            p = queue.popleft()
            for q, s in adjacency[p]:
                if similarity_matrix[source, q] == 0.0 and q != source:
                    similarity_matrix[source, q] = similarity_matrix[source, p] * s
                    queue.append(q)
    return similarity_matrix, tree


def random_guide(rng: np.random.Generator, height: int, width: int, channels: int = 3, levels: int = 256):
    """Random uint8 image; few levels give many equal (and zero) edge weights."""
    image = rng.integers(0, levels, size=(height, width, channels)).astype(np.uint8)
    return image * np.uint8(255 // max(levels - 1, 1))


# --------------------------------------------------------------------------------------
# Tree structure


def assert_rooted_spanning_tree(tree: MinimumSpanningTree) -> None:
    height, width = tree.height, tree.width
    node_count = height * width
    assert tree.order.dtype == np.int32 and tree.parent.dtype == np.int32 and tree.weight.dtype == np.float32
    assert tree.order.shape == tree.parent.shape == tree.weight.shape == (node_count,)
    assert np.array_equal(np.sort(tree.order), np.arange(node_count))
    assert tree.order[0] == 0 and tree.parent[0] == -1 and tree.weight[0] == 0
    position = np.empty(node_count, dtype=np.int64)
    position[tree.order] = np.arange(node_count)
    children = np.delete(np.arange(node_count), 0)
    parents = tree.parent[children]
    # N - 1 edges, each a grid edge, each parent before its child: connected and acyclic.
    assert np.all(parents >= 0)
    assert np.all(position[parents] < position[children])
    step = np.abs(children - parents)
    same_row = children // width == parents // width
    assert np.all(((step == 1) & same_row) | (step == width))
    assert np.all((tree.weight[children] >= 0) & (tree.weight[children] <= 1))


@pytest.mark.parametrize("levels", [2, 3, 256])
@pytest.mark.parametrize("median_size", [0, 3])
def test_tree_is_a_minimum_spanning_tree(levels, median_size):
    rng = np.random.default_rng(levels * 10 + median_size)
    guide = random_guide(rng, 9, 13, levels=levels)
    tree = build_tree(guide, median_size=median_size)
    assert_rooted_spanning_tree(tree)
    weights = grid_edge_weights(guide, median_size)
    total = sum(weights[edge] for edge in tree_edges(tree))
    assert total == pytest.approx(prim_minimum_weight(tree.height * tree.width, weights), abs=1e-9)


def test_flat_image_keeps_zero_weight_edges():
    # All edges weigh 0: a tree that dropped zero-weight edges would not span.
    tree = build_tree(np.full((6, 7, 3), 90, np.uint8))
    assert_rooted_spanning_tree(tree)
    assert np.all(tree.weight[1:] == 1.0)


def test_tree_edge_similarities_follow_guide_differences():
    guide = random_guide(np.random.default_rng(3), 8, 11)
    tree = build_tree(guide, sigma=7.0, median_size=0)
    weights = grid_edge_weights(guide, 0)
    for v in range(1, tree.height * tree.width):
        p = int(tree.parent[v])
        expected = math.exp(-weights[tuple(sorted((v, p)))] / 7.0)
        assert tree.weight[v] == pytest.approx(expected, rel=1e-6)


def test_median_filter_removes_isolated_outlier():
    guide = np.full((7, 7), 100, np.uint8)
    guide[3, 3] = 250
    assert np.all(build_tree(guide, median_size=3).weight[1:] == 1.0)
    assert np.min(build_tree(guide, median_size=0).weight[1:]) < 0.01


@pytest.mark.parametrize("shape", [(1, 1), (1, 9), (9, 1), (2, 2)])
def test_degenerate_grids(shape):
    guide = random_guide(np.random.default_rng(0), *shape)
    tree = build_tree(guide)
    assert_rooted_spanning_tree(tree)
    cost = np.random.default_rng(1).random(shape + (4,), dtype=np.float32)
    similarity, _ = tree_distance_similarity_bruteforce(guide, sigma=SIGMA, median_size=3)
    expected = (similarity @ cost.reshape(-1, 4)).reshape(cost.shape)
    np.testing.assert_allclose(aggregate(cost, tree), expected, rtol=1e-5)


# --------------------------------------------------------------------------------------
# Guide types


def assert_same_tree(a: MinimumSpanningTree, b: MinimumSpanningTree) -> None:
    assert np.array_equal(a.order, b.order)
    assert np.array_equal(a.parent, b.parent)
    np.testing.assert_allclose(a.weight, b.weight, rtol=1e-6)


@pytest.mark.parametrize("median_size", [0, 3, 5, 7])
def test_uint16_guide_is_measured_in_8bit_units(median_size):
    guide = random_guide(np.random.default_rng(5), 10, 12, levels=6)
    wide = guide.astype(np.uint16) * np.uint16(257)
    assert_same_tree(build_tree(guide, median_size=median_size), build_tree(wide, median_size=median_size))


def test_uint16_guide_uses_full_precision():
    # Differences below one 8-bit step still order the edges.
    wide = np.zeros((1, 4), np.uint16)
    wide[0] = [0, 300, 320, 1000]  # edge weights 300, 20, 680 in 16-bit units
    tree = build_tree(wide, sigma=1.0, median_size=0)
    assert tree.weight[2] == pytest.approx(math.exp(-20 / 257), rel=1e-6)


@pytest.mark.parametrize("median_size", [0, 3])
def test_gray_guide_matches_single_and_repeated_channels(median_size):
    gray = random_guide(np.random.default_rng(6), 10, 12, channels=1, levels=5)[:, :, 0]
    reference = build_tree(gray, median_size=median_size)
    assert_same_tree(reference, build_tree(gray[:, :, None], median_size=median_size))
    assert_same_tree(reference, build_tree(np.repeat(gray[:, :, None], 3, axis=2), median_size=median_size))


@pytest.mark.parametrize("channels", [2, 4, 5])
def test_any_channel_count(channels):
    guide = random_guide(np.random.default_rng(channels), 9, 10, channels=channels, levels=4)
    tree = build_tree(guide)
    assert_rooted_spanning_tree(tree)
    weights = grid_edge_weights(guide, 3)
    total = sum(weights[edge] for edge in tree_edges(tree))
    assert total == pytest.approx(prim_minimum_weight(90, weights))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_float_guide_matches_uint8(dtype):
    guide = random_guide(np.random.default_rng(8), 11, 9, levels=7)
    assert_same_tree(build_tree(guide), build_tree(guide.astype(dtype)))


def test_float_guide_with_fractional_values_is_minimum_to_its_key_resolution():
    guide = np.random.default_rng(9).random((8, 9, 3)).astype(np.float32) * 40
    tree = build_tree(guide, median_size=0)
    assert_rooted_spanning_tree(tree)
    weights = grid_edge_weights(guide.astype(np.float64), 0)
    total = sum(weights[edge] for edge in tree_edges(tree))
    # Float guides are keyed at 1/257 of a unit: each edge weight is known to 1/257, so the
    # tree is minimal up to 2 * 71 / 257 in total (and never below the true minimum).
    minimum = prim_minimum_weight(72, weights)
    assert minimum - 1e-9 <= total <= minimum + 2 * 71 / 257


def test_float_guide_keys_at_uint16_resolution():
    guide = np.random.default_rng(10).random((10, 12, 3)).astype(np.float32) * 255
    as_uint16 = np.rint(guide * 257).astype(np.uint16)
    assert_same_tree(build_tree(guide), build_tree(as_uint16))


# --------------------------------------------------------------------------------------
# Aggregation


@pytest.mark.parametrize("levels", [3, 256])
@pytest.mark.parametrize("sigma", [SIGMA, 4.0])
def test_aggregate_equals_bruteforce_tree_filter(levels, sigma):
    rng = np.random.default_rng(levels + int(sigma))
    guide = random_guide(rng, 11, 14, levels=levels)
    cost = rng.random((11, 14, 23), dtype=np.float32) * 50
    similarity, tree = tree_distance_similarity_bruteforce(guide, sigma=sigma, median_size=3)
    expected = (similarity @ cost.reshape(-1, 23).astype(np.float64)).reshape(cost.shape)
    np.testing.assert_allclose(aggregate(cost, tree), expected, rtol=1e-4)


@settings(max_examples=20, deadline=None)
@given(
    height=st.integers(1, 7),
    width=st.integers(1, 7),
    levels=st.sampled_from([2, 4, 256]),
    median_size=st.sampled_from([0, 3]),
    seed=st.integers(0, 2**32 - 1),
)
def test_aggregate_equals_bruteforce_random_shapes(height, width, levels, median_size, seed):
    rng = np.random.default_rng(seed)
    guide = random_guide(rng, height, width, levels=levels)
    cost = rng.random((height, width, 3), dtype=np.float32)
    similarity, tree = tree_distance_similarity_bruteforce(guide, sigma=SIGMA, median_size=median_size)
    expected = (similarity @ cost.reshape(-1, 3).astype(np.float64)).reshape(cost.shape)
    np.testing.assert_allclose(aggregate(cost, tree), expected, rtol=1e-4)


@pytest.mark.parametrize("shape", [(1, 1), (1, 9), (11, 14)])
def test_serial_two_pass_reference_equals_bruteforce_tree_filter(shape):
    rng = np.random.default_rng(shape[0] * 31 + shape[1])
    guide = random_guide(rng, *shape, levels=8)
    cost = rng.random(shape + (4,), dtype=np.float32) * 20
    similarity, tree = tree_distance_similarity_bruteforce(guide, sigma=SIGMA, median_size=3)
    expected = (similarity @ cost.reshape(-1, 4).astype(np.float64)).reshape(cost.shape)
    # The tree stores its similarities in float32; the brute force recomputes them in float64.
    np.testing.assert_allclose(aggregate_reference(cost, tree), expected, rtol=1e-6)
    with pytest.raises(ValueError, match="does not fit"):
        aggregate_reference(cost[:, :-1] if shape[1] > 1 else cost[:0], tree)


def smooth_tree_and_cost(shape, layers, *, seed):
    """The tree of a slightly blurred random guide and a random cost volume on its grid."""
    rng = np.random.default_rng(seed)
    guide = cv2.GaussianBlur(random_guide(rng, *shape), (0, 0), 1.0)
    return build_tree(guide), rng.random(shape + (layers,), dtype=np.float32)


@pytest.mark.parametrize("shape", [(12, 13), (140, 150)])  # the serial walk and the two-thread split
def test_winners_taken_during_the_walk_equal_a_separate_winner_pass(shape):
    tree, cost = smooth_tree_and_cost(shape, 9, seed=21)
    aggregated = aggregate(cost, tree)
    volume = np.empty_like(cost)
    disparity = aggregate_winners(cost, tree, min_disp=-3, out=volume)
    assert disparity.shape == shape and disparity.dtype == np.float32
    assert np.array_equal(disparity, winner_take_all(aggregated, -3))
    assert np.array_equal(volume, aggregated)
    # The root and the top of the second thread's subtree are finalised outside the walk.
    assert np.array_equal(aggregate_winners(cost.copy(), tree, min_disp=-3), disparity)


@pytest.mark.parametrize("shape", [(12, 13), (140, 150)])  # the serial walk and the two-thread split
def test_walk_over_the_depth_first_row_layout_is_bit_identical(shape):
    tree, cost = smooth_tree_and_cost(shape, 7, seed=22)
    layout = tree_layout(tree)
    assert np.array_equal(layout.pixel_of_row, tree.order)
    assert np.array_equal(layout.row_of_pixel[tree.order], np.arange(tree.size))
    # Pre-order: every row's parent comes earlier, and the parents are the tree's.
    assert layout.parent_row[0] == -1 and np.all(layout.parent_row[1:] < np.arange(1, tree.size))
    assert np.array_equal(tree.order[layout.parent_row[1:]], tree.parent[tree.order[1:]])
    rows = np.ascontiguousarray(cost.reshape(-1, 7)[tree.order])
    expected = aggregate_winners(cost.copy(), tree, min_disp=2)
    assert np.array_equal(aggregate_rows_winners(rows, layout, min_disp=2), expected)
    # The rows are aggregated in place, each equal to its pixel's aggregate.
    assert np.array_equal(rows, aggregate(cost, tree).reshape(-1, 7)[tree.order])


def test_layout_of_a_tree_built_elsewhere_equals_the_one_made_with_the_tree():
    tree, _ = smooth_tree_and_cost((40, 50), 3, seed=5)
    made = tree_layout(tree)
    bare = MinimumSpanningTree(order=tree.order, parent=tree.parent, weight=tree.weight, height=tree.height,
                               width=tree.width)
    derived = tree_layout(bare)
    for name in ("pixel_of_row", "row_of_pixel", "rows", "parent_row", "weight_row"):
        assert getattr(derived, name).dtype == getattr(made, name).dtype, name
        assert np.array_equal(getattr(derived, name), getattr(made, name)), name
    assert made.weight_row[0] == 0 and np.array_equal(made.weight_row, tree.weight[tree.order])
    assert tree_layout(bare) is derived  # kept with the tree


@pytest.mark.parametrize("shape", [(12, 13), (140, 150)])  # the serial walk and the two-thread split
def test_padding_layers_are_aggregated_but_never_win(shape):
    tree, cost = smooth_tree_and_cost(shape, 5, seed=31)
    layout = tree_layout(tree)
    rows = np.ascontiguousarray(cost.reshape(-1, 5)[tree.order])
    expected = aggregate_rows_winners(rows.copy(), layout, min_disp=3)
    # Three padding layers far cheaper than any real one: they would win if they competed.
    padded = np.concatenate([rows, np.full((tree.size, 3), -5.0, np.float32)], axis=1)
    aggregated = padded.copy()
    assert np.array_equal(aggregate_rows_winners(aggregated, layout, min_disp=3, num_disp=5), expected)
    # The real layers are aggregated exactly as without the padding.
    reference = rows.copy()
    aggregate_rows_winners(reference, layout, min_disp=3)
    assert np.array_equal(aggregated[:, :5], reference)
    pair = aggregate_two_rows_winners(rows.copy(), layout, rows.copy(), layout, min_disp=3)
    first, second = aggregate_two_rows_winners(padded.copy(), layout, padded.copy(), layout, min_disp=3, num_disp=5)
    assert np.array_equal(first, pair[0]) and np.array_equal(second, pair[1])
    levels = np.linspace(3, 7, tree.size, dtype=np.float32)
    unpadded = distance_rows_winners(levels, layout, min_disp=3, out=np.empty((tree.size, 5), np.float32))
    assert np.array_equal(distance_rows_winners(levels, layout, min_disp=3, out=np.empty_like(padded), num_disp=5),
                          unpadded)
    for bad in (0, 9):
        with pytest.raises(ValueError, match="num_disp"):
            aggregate_rows_winners(padded.copy(), layout, min_disp=3, num_disp=bad)


@pytest.mark.parametrize("shape", [(12, 13), (140, 150)])  # the serial walk and the two-thread split
@pytest.mark.parametrize("min_disp", [0, -4])
def test_distance_cost_computed_in_the_walk_equals_the_stored_cost(shape, min_disp):
    rng = np.random.default_rng(24)
    tree, _ = smooth_tree_and_cost(shape, 1, seed=24)
    layout = tree_layout(tree)
    layers = 9
    levels = (min_disp + rng.random(tree.size) * (layers - 1)).astype(np.float32)
    levels[rng.random(tree.size) < 0.3] = np.nan
    # The cost it stands for: |min_disp + i - level|, 0 where the level is NaN.
    stored = np.abs(np.float32(min_disp) + np.arange(layers, dtype=np.float32) - levels[:, None])
    stored[np.isnan(levels)] = 0.0
    expected = aggregate_rows_winners(np.ascontiguousarray(stored, np.float32), layout, min_disp=min_disp)
    scratch = np.full((tree.size, layers), np.nan, np.float32)  # contents must not matter
    assert np.array_equal(distance_rows_winners(levels, layout, min_disp=min_disp, out=scratch), expected)
    with pytest.raises(ValueError, match="one value per row"):
        distance_rows_winners(levels[:-1], layout, min_disp=min_disp, out=scratch)


def test_constant_cost_is_aggregated_proportionally_per_pixel():
    rng = np.random.default_rng(13)
    guide = random_guide(rng, 20, 30, levels=5)
    tree = build_tree(guide)
    per_disparity = np.linspace(0.5, 9.0, 12, dtype=np.float32)
    cost = np.broadcast_to(per_disparity, (20, 30, 12)).copy()
    result = aggregate(cost, tree)
    support = aggregate(np.ones((20, 30, 1), np.float32), tree)
    np.testing.assert_allclose(result, support * per_disparity, rtol=1e-5)
    # The support sums S(p, q) over all q: at least S(p, p) = 1, at most N.
    assert np.all(support >= 1.0) and np.all(support <= 600)


def test_flat_guide_sums_the_whole_volume():
    cost = np.random.default_rng(14).random((5, 6, 4), dtype=np.float32)
    result = aggregate(cost, build_tree(np.zeros((5, 6), np.uint8)))
    np.testing.assert_allclose(result, np.broadcast_to(cost.sum(axis=(0, 1)), cost.shape), rtol=1e-5)


def test_in_place_and_out_argument():
    rng = np.random.default_rng(15)
    guide = random_guide(rng, 15, 16)
    cost = rng.random((15, 16, 7), dtype=np.float32)
    tree = build_tree(guide)
    expected = aggregate(cost, tree)
    out = np.full_like(cost, np.nan)
    assert aggregate(cost, tree, out=out) is out
    np.testing.assert_array_equal(out, expected)
    in_place = cost.copy()
    assert aggregate(in_place, tree, out=in_place) is in_place
    np.testing.assert_array_equal(in_place, expected)


def test_non_contiguous_cost_is_accepted():
    rng = np.random.default_rng(16)
    tree = build_tree(random_guide(rng, 6, 8))
    cost = rng.random((6, 8, 10), dtype=np.float32)
    np.testing.assert_allclose(aggregate(cost[:, :, ::2], tree), aggregate(np.ascontiguousarray(cost[:, :, ::2]), tree))


def test_results_are_deterministic():
    rng = np.random.default_rng(17)
    guide = random_guide(rng, 140, 130, levels=4)
    cost = rng.random((140, 130, 9), dtype=np.float32)
    first, second = build_tree(guide), build_tree(guide.copy())
    assert_same_tree(first, second)
    assert np.array_equal(first.weight, second.weight)
    assert np.array_equal(aggregate(cost, first), aggregate(cost, second))


# --------------------------------------------------------------------------------------
# Errors


@pytest.mark.parametrize("sigma", [0.0, -1.0, float("nan"), float("inf")])
def test_bad_sigma(sigma):
    with pytest.raises(OptionError):
        build_tree(np.zeros((4, 4), np.uint8), sigma=sigma)


@pytest.mark.parametrize("median_size", [2, 4, -3])
def test_bad_median_size(median_size):
    with pytest.raises(OptionError):
        build_tree(np.zeros((4, 4), np.uint8), median_size=median_size)


@pytest.mark.parametrize(
    "guide",
    [np.zeros((0, 4), np.uint8), np.zeros((4,), np.uint8), np.zeros((2, 2, 2, 2), np.uint8),
     np.zeros((4, 4), np.int64), np.full((4, 4), np.nan, np.float32), np.full((4, 4, 3), -np.inf), [[1, 2], [3, 4]]],
)
def test_bad_guide(guide):
    with pytest.raises(ImageReadError):
        build_tree(guide)


def test_cost_shape_must_match_tree():
    tree = build_tree(np.zeros((4, 5), np.uint8))
    with pytest.raises(ValueError):
        aggregate(np.zeros((5, 4, 3), np.float32), tree)
    with pytest.raises(ValueError):
        aggregate(np.zeros((4, 5, 3), np.float32), tree, out=np.zeros((4, 5, 3), np.float64))


def test_build_trees_matches_build_tree_on_each_guide_and_keeps_the_layouts():
    import numba
    rng = np.random.default_rng(12)
    # Two guides go to the two-thread kernel, the third is built alone; shapes differ.
    guides = [rng.integers(0, 256, (40, 70, 3), dtype=np.uint8), rng.uniform(0, 255, (40, 70, 3)).astype(np.float32),
              rng.integers(0, 256, (23, 31), dtype=np.uint8)]
    for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
        numba.set_num_threads(threads)
        try:
            trees = build_trees(guides, sigma=20.0, median_size=3)
        finally:
            numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        assert len(trees) == len(guides)
        for tree, guide in zip(trees, guides):
            assert (tree.height, tree.width) == guide.shape[:2]
            alone = build_tree(guide, sigma=20.0, median_size=3)
            for name in ("order", "parent", "weight"):
                np.testing.assert_array_equal(getattr(tree, name), getattr(alone, name))
            # The layout was made with the tree and is reused, not rebuilt.
            assert tree_layout(tree) is tree_layout(tree)
            np.testing.assert_array_equal(tree_layout(tree).row_of_pixel, tree_layout(alone).row_of_pixel)
