"""A call with room on CPython's frame stack, against its chunk thrashing while numba compiles.

CPython 3.11 and 3.12 keep the frames of Python functions in chunks of 16 KiB: a call
that does not fit in the current chunk maps a new one, and the return unmaps it.  A loop
that calls at exactly that depth maps and unmaps a chunk on every call (CPython issue
gh-142183, fixed in 3.13 by keeping one chunk).  numba's compiler is such a loop, and
where its depth falls depends on how deep the caller is: under ``sb-decode``'s click
command, a first Hybrid decode of a 640 x 480 pair made a million 16 KiB mappings, 6-8 s
of system time, and the fill's slice compiled in 16-20 s instead of 10.

:func:`call_with_stack_room` calls a function from a frame that asks for 133 KiB of the
stack (an evaluation stack of :data:`ROOM_SLOTS` slots it never uses): CPython gives it
a chunk of 256 KiB, whose ~120 KiB above it hold the frames of everything the call runs,
so no chunk is mapped or unmapped within it.  It costs one 256 KiB mapping and leaves
nothing behind (the chunk goes with the frame); elsewhere it is a plain call.
"""

from __future__ import annotations

import types

#: Evaluation-stack slots of the roomy frame, 8 bytes each.
ROOM_SLOTS = 17000


def _call(function, args, kwargs):
    return function(*args, **kwargs)


_call_with_room = types.FunctionType(_call.__code__.replace(co_stacksize=ROOM_SLOTS), globals(), "_call_with_room")


def call_with_stack_room(function, *args, **kwargs):
    """``function(*args, **kwargs)``, called with ~120 KiB of CPython's frame stack free above it.

    Parameters
    ----------
    function : callable
    *args, **kwargs
        Passed on.

    Returns
    -------
    Whatever ``function`` returns (exceptions pass through).
    """
    return _call_with_room(function, args, kwargs)


__all__ = ["ROOM_SLOTS", "call_with_stack_room"]
