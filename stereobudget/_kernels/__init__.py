"""Low-level speed tricks shared by the numba kernels: SIMD IR, prefetch, threads, scratch pools, JIT flags."""

from .._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    '_simd': ['LANES', 'MIN_VECTOR_LENGTH', 'first_min', 'skewed_block_copy', 'blend_rows_first_min', 'MAX_PERIOD_CHANNELS', 'PERIOD_READ_PAST', 'period_lanes', 'MAX_PERIOD_LANES', 'periodic_corner_sum', 'FIXED_LANES', 'fixed_path_step'],
    '_prefetch': ['LINE_FLOATS', 'prefetch_for_write', 'prefetch_row'],
    '_parallel': ['run_parts', 'part_bounds', 'take', 'fill_zero'],
    '_jit': ['NO_REFCOUNTS'],
    '_first_run': ['kernels_cached', 'announce_first_compile'],
    '_scratch': ['SPARE_BYTES', 'LARGE_BYTES', 'keep_freed_memory', 'avoid_huge_pages', 'empty_volume', 'frame', 'holding_no_large_spares', 'zeroed_volume', 'recycle', 'in_use', 'begin_keeping', 'end_keeping', 'keeping', 'spare_bytes', 'release'],
})
