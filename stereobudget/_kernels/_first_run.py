"""Whether the numba kernels still have to be compiled: the "first use" notice.

Every kernel is ``njit(cache=True)``: numba compiles it on first use and keeps the
machine code in a cache (``__pycache__`` beside the module, or ``$NUMBA_CACHE_DIR``),
checked against the module's source file.  After an install or an upgrade the cache is
empty and the first decode of each method spends seconds compiling (docs/performance.md).
Two notices say so:

* :func:`kernels_cached` looks at the cache index of the kernels the decoders use, so the
  command line can say so before it starts (:func:`announce_first_compile`);
* :func:`compile_notice` listens, while a decode runs, for numba actually compiling (a
  cache miss, whatever the method or the input's type) and says so at the first one.

Either says it once per process.  ``python -m stereobudget.warm`` compiles every method's
kernels ahead (:mod:`stereobudget.warm`).
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import threading

log = logging.getLogger("stereobudget")

#: Modules whose kernels the decoders run (the tree routes, the semi-global routes and their
#: census cost): if none of them is cached, nothing is.
PROBE_MODULES = ("stereobudget.aggregate._tree", "stereobudget.aggregate._semiglobal", "stereobudget.cost._census")
#: Wall time of the first Hybrid ``sb-decode`` (with the range estimate, one 8-bit RGB
#: 640x480 pair) from an empty NUMBA_CACHE_DIR on the project's 2-core machine, idle: a median of
#: 11.3 s, with a second process compiling the decode's later kernels (``stereobudget.warm.start_hybrid_tail``;
#: longer on a busy machine).
COMPILE_SECONDS = 11
#: Wall time of each method's first decode on one core (8-bit RGB, 640x480, ``--max-disp 64``)
#: on the project's 2-core machine, idle, one after another from an empty cache in this order (a
#: later method reuses the kernels an earlier one compiled): see docs/performance.md.
METHOD_COMPILE_SECONDS = {"hybrid": 22, "sparse": 11, "downsample": 12, "full": 5, "range": 3}
WARM_COMMAND = "python -m stereobudget.warm"

_announced = threading.Event()


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
    text = (f"compiling kernels, first run only, ~{COMPILE_SECONDS} s "
            f"({WARM_COMMAND} compiles every method's at once)")
    (emit or log.warning)(text)
    _announced.set()
    return True


def _compile_text(method):
    seconds = METHOD_COMPILE_SECONDS.get(method, COMPILE_SECONDS)
    what = ("the range estimate's kernels" if method == "range" else
            f"the {method} decoder's kernels" if method else "kernels")
    return (f"compiling {what} (first use after an install), ~{seconds} s on a 2-core machine; "
            f"{WARM_COMMAND} compiles every method's at once")


def _listener(method, emit):
    """A numba compile listener that gives the notice at its first start event."""
    from numba.core import event

    class Listener(event.Listener):
        def on_start(self, _event):
            if not _announced.is_set():
                _announced.set()
                (emit or log.warning)(_compile_text(method))

        def on_end(self, _event):
            pass

    return Listener()


_active = threading.local()


@contextlib.contextmanager
def compile_notice(method: str | None = None, emit=None):
    """While the block runs, say once per process when numba starts compiling a kernel.

    numba fires ``numba:compile`` only on a cache miss, so this speaks whenever
    compiling really happens (any method, any input type), and never when the kernels
    load from the cache.  Nested blocks listen once.  ``emit`` as in
    :func:`announce_first_compile`.
    """
    if getattr(_active, "depth", 0) or _announced.is_set():
        _active.depth = getattr(_active, "depth", 0) + 1
        try:
            yield
        finally:
            _active.depth -= 1
        return
    try:
        from numba.core import event
        listener = _listener(method, emit)
        event.register("numba:compile", listener)
    except Exception:  # noqa: BLE001 -- numba without the event API: no notice rather than a failure
        listener = None
    _active.depth = 1
    try:
        yield
    finally:
        _active.depth = 0
        if listener is not None:
            event.unregister("numba:compile", listener)


__all__ = ["PROBE_MODULES", "COMPILE_SECONDS", "METHOD_COMPILE_SECONDS", "WARM_COMMAND", "kernels_cached",
           "announce_first_compile", "compile_notice"]
