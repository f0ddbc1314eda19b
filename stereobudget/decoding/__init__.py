"""The decoders of paper Fig. 2 (sparse, hybrid, downsample, full), one module each; their
parameters, tiling and memory estimate; the opt-in :class:`Decoder` for a sequence of decodes;
the estimate of the disparity range and the checks behind the warnings of ``sb-decode``."""

from .._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    '_params': ['DecoderParams', 'DecodeResult', 'check_inputs', 'adapt_to_noise'],
    '_hybrid': ['hybrid_weight'],
    '_decoders': ['decode', 'Decoder', 'shared_decoder'],
    '_tiling': ['band_samples', 'DEFAULT_TILE_OVERLAP', 'MIN_TILE_ROWS', 'TILED_METHODS', 'auto_tile_rows', 'decode_tiled'],
    '_memory': ['decode_memory'],
    '_temporal': ['TemporalParams', 'TemporalSearch'],
    '_methods': ['METHODS', 'DEFAULT_METHOD'],
    '_disprange': ['AUTO', 'RangeEstimate', 'estimate_disparity_range', 'is_auto', 'resolve_range'],
    '_checks': ['DecodeWarning', 'limit_shares', 'psnr_at_samples', 'setup_warnings', 'result_warnings'],
})
