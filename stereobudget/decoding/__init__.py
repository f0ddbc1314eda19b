"""The decoders of paper Fig. 2 (sparse, hybrid, downsample, full), one module each and one record each
(:data:`METHOD_RECORDS`); their parameters, tiling and memory model; the opt-in :class:`Decoder` for a sequence of decodes;
the estimate of the disparity range and the checks behind the warnings of ``sb-decode``."""

from .._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    '_params': ['DecoderParams', 'HYBRID_AGGREGATIONS', 'FULL_COSTS', 'RIGHT_CHECKS', 'DecodeResult', 'check_inputs',
                'adapt_to_noise', 'method_for'],
    '_hybrid': ['hybrid_weight'],
    '_decoders': ['decode', 'Decoder', 'shared_decoder'],
    '_tiling': ['band_samples', 'DEFAULT_TILE_OVERLAP', 'MIN_TILE_ROWS', 'auto_tile_rows', 'decode_tiled'],
    '_memory': ['estimate_decode_memory', 'check_decode_memory', 'decode_memory'],
    '_temporal': ['TemporalParams', 'TemporalSearch'],
    '_methods': ['MethodRecord', 'METHOD_RECORDS', 'METHODS', 'DEFAULT_METHOD', 'TILED_METHODS'],
    '_disprange': ['AUTO', 'RangeEstimate', 'estimate_disparity_range', 'is_auto', 'resolve_range', 'top_share',
                   'widened_max'],
    '_checks': ['DecodeWarning', 'limit_shares', 'psnr_at_samples', 'psnr_at_zero_disparity', 'setup_warnings',
                'result_warnings'],
})
