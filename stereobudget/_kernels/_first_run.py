"""Whether the numba kernels still have to be compiled: the "first run only" notice.

Every kernel is ``njit(cache=True)``: numba compiles it on first use and keeps the
machine code in a cache (``__pycache__`` beside the module, or ``$NUMBA_CACHE_DIR``),
checked against the module's source file.  After an install or an upgrade the cache is
empty and the first decode spends minutes compiling, silently; :func:`kernels_cached`
looks at the cache index of the kernels the decoders use, so the command line
can say so before it starts.
"""

from __future__ import annotations

import importlib
import logging

log = logging.getLogger("stereobudget")

#: Modules whose kernels the decoders run (the tree routes, the semi-global routes and their
#: census cost): if none of them is cached, nothing is.
PROBE_MODULES = ("stereobudget.aggregate._tree", "stereobudget.aggregate._semiglobal", "stereobudget.cost._census")
#: Time of a full compile (Hybrid with the range estimate, one 8-bit RGB pair): 317 s of
#: CPU on the project's 2-core machine (numba compiles on one thread), measured with an
#: empty NUMBA_CACHE_DIR.
COMPILE_SECONDS = 300


def _dispatchers(module):
    from numba.core.registry import CPUDispatcher
    for value in vars(module).values():
        if isinstance(value, CPUDispatcher) and getattr(value.py_func, "__module__", None) == module.__name__:
            yield value


def kernels_cached(modules=PROBE_MODULES) -> bool | None:
    """True when some kernel of ``modules`` has compiled code in numba's cache for its current source.

    False: none has (a fresh install or upgrade; the next decode compiles).  None: it
    cannot be told (numba's cache internals differ from what this reads).
    """
    try:
        for name in modules:
            for dispatcher in _dispatchers(importlib.import_module(name)):
                cache = dispatcher._cache
                # numba's index is empty when missing or made for another source.
                if cache._cache_file._load_index():
                    return True
        return False
    except Exception:  # noqa: BLE001 -- private numba API: no notice rather than a failure
        return None


def announce_first_compile(emit=None) -> bool:
    """Print ``compiling kernels, first run only, ~N s`` when the kernels are not cached yet.

    ``emit(text)`` prints the line (default: the ``stereobudget`` logger at WARNING, so
    it reaches stderr unless ``-q``).  Returns whether it was printed.
    """
    if kernels_cached() is not False:
        return False
    text = f"compiling kernels, first run only, ~{COMPILE_SECONDS} s"
    (emit or log.warning)(text)
    return True


__all__ = ["PROBE_MODULES", "COMPILE_SECONDS", "kernels_cached", "announce_first_compile"]
