"""Software prefetch for numba kernels that write rows at data-dependent addresses.

Writing a cost-volume row to the row of a tree's layout (``row_of_pixel[p]``) lands at an
address the hardware prefetcher cannot guess, so each of the row's cache lines is first
read from memory at the moment of the write.  Asking for the lines of a row a few pixels
ahead overlaps those reads with the work on the current pixel.

``llvm.prefetch`` is declared with its typed-pointer name (``.p0i8``), which the LLVM of
every numba this package supports accepts (LLVM 15 and later upgrade it to ``.p0``).
"""

from __future__ import annotations

from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

#: Floats per cache line (64 bytes of float32).
LINE_FLOATS = 16


@intrinsic
def prefetch_for_write(typingctx, array, index):
    """Hint that ``array[index]`` (a 1-D array, unchecked index) will soon be written."""
    if not isinstance(array, types.Array) or array.ndim != 1 or not isinstance(index, types.Integer):
        return None
    sig = types.void(array, index)

    def codegen(context, builder, signature, args):
        array_type = signature.args[0]
        view = context.make_array(array_type)(context, builder, args[0])
        pointer = cgutils.get_item_pointer(context, builder, array_type, view, [args[1]], wraparound=False)
        byte_pointer = ir.IntType(8).as_pointer()
        int32 = ir.IntType(32)
        function = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(ir.VoidType(), [byte_pointer, int32, int32, int32]),
            "llvm.prefetch.p0i8")
        # (address, write = 1, locality = 3: keep in all cache levels, data cache = 1)
        builder.call(function, [builder.bitcast(pointer, byte_pointer), ir.Constant(int32, 1),
                                ir.Constant(int32, 3), ir.Constant(int32, 1)])
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True, inline="always")
def prefetch_row(flat, row, row_length):
    """Prefetch (for writing) the cache lines of row ``row`` of an (N, row_length) array seen as ``flat``:
    all of them when the array starts a line or the row is not a whole number of lines."""
    start = row * row_length
    for offset in range(0, row_length, LINE_FLOATS):
        prefetch_for_write(flat, start + offset)
    if row_length % LINE_FLOATS != 0:
        # A row of whole lines starts a line in a line-aligned volume
        # (stereobudget._kernels.empty_volume); any other row may end in one more.
        prefetch_for_write(flat, start + row_length - 1)
