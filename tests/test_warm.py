"""python -m stereobudget.warm runs every kernel a method's decode runs, and refuses unknown methods."""

from __future__ import annotations

import pytest

from stereobudget.warm import main, warm


def test_warming_a_method_decodes_with_it():
    reports = []
    seconds = warm(["sparse"], jobs=1, kinds=["gray"], report=reports.append)
    assert seconds > 0 and len(reports) == 1 and reports[0].startswith("sparse: ")


def test_an_unknown_method_is_refused(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--methods", "hybrid,sgbm"])
    assert exit_info.value.code == 2 and "unknown method(s) sgbm" in capsys.readouterr().err
