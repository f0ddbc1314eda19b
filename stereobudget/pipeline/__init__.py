"""One pair, one file, one frame: the encode and decode paths that the commands, the batch runners and the
frame streams all call (outputs checked first, inputs read, decode, Î2, checks, atomic writes)."""

from .._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    '_jobs': ['EncodeJob', 'encode_one', 'DecodeJob', 'recover_right_image', 'decode_file', 'decode_arrays'],
    '_outputs': ['prepare_outputs', 'check_job_outputs'],
})
