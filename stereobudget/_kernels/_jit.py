"""numba options shared by the hot kernels.

Every array view a numba function makes (``row = volume[v]``, ``buffer[x]``) takes a
reference on the array's memory: an atomic increment, and a decrement when the view
dies.  numba's pruning pass drops such pairs only within simple control flow; in the
down pass of a tree walk, with its two branches, a pair per node stayed (and half the
pass's time: measured with scripts/bench.py).  Kernels that allocate nothing and
return no array can be compiled without reference counting at all (the arrays they are
given are kept alive by their caller); the range kernels that need scratch arrays
allocate them and hand the work to such a kernel.
"""

from __future__ import annotations

from numba.core import cpu
from numba.core.compiler import CompilerBase, DefaultPassBuilder

#: ``njit`` options of a kernel that allocates no array and returns none: numba's
#: reference counting off (an option of numba's own CPU target; where a numba version
#: lacks it, the kernels compile with reference counting, as they did before).
NO_REFCOUNTS = {"_nrt": False} if hasattr(cpu.CPUTargetOptions, "_nrt") else {}


class _ArgumentsDoNotAlias(CompilerBase):
    """numba's nopython pipeline, with every pointer argument of the compiled function marked
    ``noalias``: LLVM then keeps values in registers across stores to another array and
    vectorises the loops.  numba compiles the bodies of its parallel loops so; without it
    the range kernels ran 2x slower than those bodies (the census mix: 31 against 13 ms
    on one thread, 640 x 480 x 65)."""

    def define_pipelines(self):
        self.state.flags.noalias = True
        return [DefaultPassBuilder.define_nopython_pipeline(self.state)]


#: ``njit`` options of a range kernel, one that :func:`stereobudget._kernels.run_parts` runs
#: on threads: it releases the GIL, and it is compiled as numba compiles a parallel loop's
#: body (``error_model="numpy"``: no ZeroDivisionError checks in the loops; arguments that
#: do not alias) and without reference counts (:data:`NO_REFCOUNTS`): it allocates nothing
#: (scratch comes from ``run_parts(..., scratch=...)``).  With reference counts, the warp's
#: calls of an inlined helper took 30 ms a 640 x 480 frame on one thread, against 18 ms.
#: Callers must not pass one array's memory in two arguments that the kernel writes through.
RANGE_KERNEL = {"nogil": True, "error_model": "numpy", "pipeline_class": _ArgumentsDoNotAlias, **NO_REFCOUNTS}
#: :data:`RANGE_KERNEL` with numba's reference counts, for a range kernel of a few large
#: items that calls kernels allocating their own memory (two trees, two walks).
RANGE_KERNEL_COUNTED = {"nogil": True, "error_model": "numpy", "pipeline_class": _ArgumentsDoNotAlias}
