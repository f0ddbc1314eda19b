"""Many inputs in one run: input expansion, batch items with the up-to-date rule, runners (threads, processes,
dask) and frame streams; each item or frame goes through :mod:`stereobudget.pipeline`."""

from .._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    '_recipes': ['RECIPE_SUFFIX', 'recipe_path', 'make_recipe', 'recipe_difference', 'write_recipes'],
    '_stream': ['encode_stream', 'decode_stream'],
    '_inputs': ['IMAGE_EXTENSIONS', 'SAMPLE_EXTENSIONS', 'TEMPLATE_FIELDS', 'expand_inputs', 'has_template', 'template_fields', 'uses_field', 'expand_template', 'check_distinct_outputs', 'Pair', 'pair_by_stem', 'read_manifest'],
    '_items': ['encode_job', 'decode_job'],
    # The jobs a batch runs are the pipeline's (the arguments of run_jobs).
    '_runners': ['default_jobs', 'run_jobs', 'EncodeJob', 'DecodeJob'],
})
