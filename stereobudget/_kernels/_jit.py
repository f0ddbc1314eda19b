"""numba options shared by the hot kernels.

Every array view a numba function makes (``row = volume[v]``, ``buffer[x]``) takes a
reference on the array's memory: an atomic increment, and a decrement when the view
dies.  numba's pruning pass drops such pairs only within simple control flow; in the
down pass of a tree walk, with its two branches, a pair per node stayed (and half the
pass's time: measured with scripts/bench.py).  Kernels that allocate nothing and
return no array can be compiled without reference counting at all (the arrays they are
given are kept alive by their caller); the parallel kernels that need scratch arrays
allocate them and hand the work to such a kernel.
"""

from __future__ import annotations

from numba.core import cpu

#: ``njit`` options of a kernel that allocates no array and returns none: numba's
#: reference counting off (an option of numba's own CPU target; where a numba version
#: lacks it, the kernels compile with reference counting, as they did before).
NO_REFCOUNTS = {"_nrt": False} if hasattr(cpu.CPUTargetOptions, "_nrt") else {}
