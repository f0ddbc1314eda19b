"""Reading and writing: the sample file, frame streams, raw sample grids, images, Bayer mosaics, disparity maps, atomic output, size and memory limits."""

from .._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    '_samples': ['CHANNEL_ORDERS', 'SampleSet', 'MAGIC', 'VERSION_MAJOR', 'VERSION_MINOR', 'HEADER_SIZE_V1_0', 'MAX_HEADER_LENGTH', 'CHANNEL_ORDER_CODES', 'PATTERN_CODES', 'DTYPE_CODES', 'write_samples', 'read_samples', 'save_samples', 'load_samples', 'header_dict', 'probe'],
    '_codecs': ['CODEC_IDS', 'CODEC_CHOICES', 'LOSSY_CODECS', 'IMAGE_CODECS', 'DEFAULT_QUALITY', 'resolve_codec', 'have_jxl'],
    '_rawgrid': ['RAW_FORMATS', 'raw_frame_layout', 'check_raw_frame', 'grid_payload'],
    '_stream': ['sample_frames', 'raw_frames', 'holds_several_frames'],
    '_images': ['sniff_image_size', 'read_image', 'RAW_PIXEL_FORMATS', 'parse_raw_size', 'read_raw', 'encode_image_bytes', 'write_image'],
    '_mosaic': ['BAYER_PATTERNS', 'MOSAIC_ORDERS', 'mosaic_image', 'shifted_order', 'rgb_with_gaps'],
    '_disparity': ['logger', 'DISPARITY_EXTENSIONS', 'STREAM_FORMATS', 'PNG_SCALE', 'PNG_MAX_DISPARITY', 'write_disparity', 'read_disparity', 'pfm_frames', 'disparity_preview', 'SCALE_BAR_MIN_WIDTH', 'with_scale_bar', 'write_preview'],
    '_atomic': ['STDIO', 'redeliver_swallowed_interrupts', 'atomic_write', 'interrupts_deferred', 'write_output_bytes', 'read_input_bytes', 'display_name', 'check_output_path', 'written_together', 'standard_stream', 'stdin_or', 'stdout_error'],
    '_limits': ['MAX_DIMENSION', 'MAX_PIXELS', 'MAX_INPUT_BYTES', 'dimension_problem', 'DEFAULT_MEMORY_FRACTION', 'MEMORY_LIMIT_ENV', 'available_memory', 'parse_size', 'format_size', 'default_memory_limit'],
})
