"""Cost aggregation and winners: Yang's minimum-spanning-tree filter, semi-global paths, winner-take-all, LR refinement, the weighted median of rejected pixels."""

from .._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    '_mst': ['MinimumSpanningTree', 'TreeLayout', 'build_tree', 'build_trees', 'tree_layout'],
    '_tree': ['aggregate', 'aggregate_winners', 'aggregate_rows_winners', 'aggregate_two_rows_winners', 'distance_rows_winners'],
    '_winner': ['subpixel_winner', 'refined_winner', 'winner_take_all'],
    '_refine': ['right_disparity_from_left', 'left_right_stable', 'nonlocal_refinement', 'left_right_refined_rows', 'pair_trees', 'full_pair_disparity', 'median_filter_disparity', 'fill_from_row'],
    '_pair_volumes': ['pair_cost_rows'],
    '_planes': ['segment_image', 'fit_segment_planes', 'plane_refinement'],
    '_weighted_median': ['weighted_median_fill'],
    '_reference': ['aggregate_reference', 'left_right_refinement_reference', 'plane_refinement_reference', 'weighted_median_fill_reference'],
    '_semiglobal': ['fixed_point_scale', 'pixel_margins', 'semiglobal_aggregate', 'semiglobal_aggregate_reference', 'semiglobal_winners', 'semiglobal_disparities'],
})
