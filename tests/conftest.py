"""Fixtures shared by several test modules."""

import numpy as np
import pytest


def _right_view_reference(left_cost, min_disp):
    """C_R(x, d) = C_L(x + d, d), the border column where x + d leaves the image (numpy)."""
    h, w, nd = left_cost.shape
    columns = np.clip(np.arange(w)[:, None] + min_disp + np.arange(nd)[None, :], 0, w - 1)
    return left_cost[:, columns, np.arange(nd)[None, :]]


@pytest.fixture
def right_view_reference():
    """The right view's cost volume from the left one, by plain numpy indexing."""
    return _right_view_reference
