"""stereobudget._kernels._stack: a call from a frame with room on CPython's frame stack."""

import sys

import pytest

from stereobudget._kernels._stack import ROOM_SLOTS, _call_with_room, call_with_stack_room


def test_the_call_passes_arguments_results_and_exceptions_through():
    assert call_with_stack_room(lambda a, b=0, *, c: (a, b, c), 1, b=2, c=3) == (1, 2, 3)
    with pytest.raises(KeyError):
        call_with_stack_room({}.__getitem__, "missing")


def test_the_calling_frame_asks_for_the_room():
    assert _call_with_room.__code__.co_stacksize == ROOM_SLOTS
    assert ROOM_SLOTS * 8 > 128 * 1024          # past 128 KiB: CPython gives it a 256 KiB chunk


def test_deep_calls_inside_the_room_run():
    def depth(n):
        return 0 if n == 0 else 1 + depth(n - 1)
    assert call_with_stack_room(depth, min(500, sys.getrecursionlimit() - 100)) == min(500,
                                                                                       sys.getrecursionlimit() - 100)
