"""Many inputs in one run: input expansion, jobs, runners (threads, processes, dask) and frame streams."""

from .._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    '_recipes': ['RECIPE_SUFFIX', 'recipe_path', 'make_recipe', 'recipe_difference', 'write_recipes'],
    '_stream': ['encode_stream', 'decode_stream'],
    '_inputs': ['IMAGE_EXTENSIONS', 'SAMPLE_EXTENSIONS', 'TEMPLATE_FIELDS', 'expand_inputs', 'has_template', 'template_fields', 'uses_field', 'expand_template', 'check_distinct_outputs', 'Pair', 'pair_by_stem', 'read_manifest'],
    '_outputs': ['outputs_up_to_date', 'check_job_outputs'],
    '_jobs': ['EncodeJob', 'encode_job', 'DecodeJob', 'recover_right_image', 'decode_file', 'decode_arrays', 'decode_job'],
    '_runners': ['default_jobs', 'run_jobs'],
})
