"""Click commands ``sb-encode`` and ``sb-decode`` (installed as ``stereobudget.cli``)."""
