"""The index of a row's first minimum, eight lanes at a time.

Every winner-take-all (:func:`stereobudget.winner.subpixel_winner`) scans a pixel's
cost layers for the first smallest one; three tree walks of a Hybrid decode do it once
per pixel each.  Written as a loop, LLVM keeps that scan scalar: a float minimum
carried with its index does not vectorise without fast-math flags, and fast math would
change which of two equal costs wins.  :func:`first_min` writes the vector code
itself, as plain LLVM IR (no target-specific intrinsics): each of eight lanes keeps the
smallest value it has seen and where it saw it, the lanes are merged by value and then
by index, and the result is exactly the scalar scan's, ties and NaN included.
"""

from __future__ import annotations

from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic, overload

#: Lanes of one vector (eight float32: one AVX register).
LANES = 8
#: Rows shorter than this are scanned by the scalar loop (the vector code reads two vectors).
MIN_VECTOR_LENGTH = 2 * LANES


def _better(builder, value, index, other_value, other_index):
    """Per lane, the better of two (value, index) candidates: the smaller value, ties to the smaller index."""
    less = builder.fcmp_ordered("<", other_value, value)
    tie = builder.and_(builder.fcmp_ordered("==", other_value, value),
                       builder.icmp_signed("<", other_index, index))
    take = builder.or_(less, tie)
    return builder.select(take, other_value, value), builder.select(take, other_index, index)


@intrinsic
def _first_min_vector(typingctx, array):
    """Index of the first minimum of a C-contiguous float32 row of >= 16 elements whose
    first element is not NaN (NaN elements never win, as in the scalar scan)."""
    if not (isinstance(array, types.Array) and array.ndim == 1 and array.dtype == types.float32
            and array.layout == "C"):
        return None
    signature = types.int64(array)

    def codegen(context, builder, sig, args):
        view = context.make_array(sig.args[0])(context, builder, args[0])
        length = cgutils.unpack_tuple(builder, view.shape, 1)[0]
        f32, i32, i64 = ir.FloatType(), ir.IntType(32), ir.IntType(64)
        vector, indices = ir.VectorType(f32, LANES), ir.VectorType(i32, LANES)
        data = builder.bitcast(view.data, f32.as_pointer())
        lane_numbers = ir.Constant(indices, list(range(LANES)))
        infinity = ir.Constant(vector, [float("inf")] * LANES)

        def load(offset):
            """Elements [offset, offset + 8) (NaN read as +inf) and their indices."""
            values = builder.load(builder.bitcast(builder.gep(data, [offset]), vector.as_pointer()), align=4)
            values = builder.select(builder.fcmp_unordered("uno", values, values), infinity, values)
            start = builder.insert_element(ir.Constant(indices, ir.Undefined), builder.trunc(offset, i32),
                                           ir.Constant(i32, 0))
            start = builder.shuffle_vector(start, start, ir.Constant(indices, [0] * LANES))
            return values, builder.add(start, lane_numbers)

        def update(best, best_index, values, value_indices):
            # Each lane sees its elements in non-decreasing index order, so a strict < keeps
            # the first of equal values.
            smaller = builder.fcmp_ordered("<", values, best)
            return builder.select(smaller, values, best), builder.select(smaller, value_indices, best_index)

        pair = ir.Constant(i64, 2 * LANES)
        one = ir.Constant(i64, 1)
        pairs = builder.sdiv(length, pair)
        first_a, first_a_index = load(ir.Constant(i64, 0))
        first_b, first_b_index = load(ir.Constant(i64, LANES))
        entry = builder.block
        loop = builder.append_basic_block("first_min.loop")
        done = builder.append_basic_block("first_min.done")
        builder.cbranch(builder.icmp_signed(">", pairs, one), loop, done)

        # Two accumulators, A and B, over alternating vectors: two independent chains.
        builder.position_at_end(loop)
        step = builder.phi(i64)
        a, a_index, b, b_index = (builder.phi(t) for t in (vector, indices, vector, indices))
        start = builder.mul(step, pair)
        next_a, next_a_index = update(a, a_index, *load(start))
        next_b, next_b_index = update(b, b_index, *load(builder.add(start, ir.Constant(i64, LANES))))
        next_step = builder.add(step, one)
        loop_end = builder.block
        for phi, initial, following in ((step, one, next_step), (a, first_a, next_a), (a_index, first_a_index, next_a_index),
                                        (b, first_b, next_b), (b_index, first_b_index, next_b_index)):
            phi.add_incoming(initial, entry)
            phi.add_incoming(following, loop_end)
        builder.cbranch(builder.icmp_signed("<", next_step, pairs), loop, done)

        builder.position_at_end(done)
        merged = []
        for initial, following in ((first_a, next_a), (first_a_index, next_a_index), (first_b, next_b),
                                   (first_b_index, next_b_index)):
            phi = builder.phi(initial.type)
            phi.add_incoming(initial, entry)
            phi.add_incoming(following, loop_end)
            merged.append(phi)
        a, a_index, b, b_index = merged
        # The last (< 16) elements as two vectors that may overlap ones already seen: a
        # repeated element brings its own index, and each lane's indices still do not decrease.
        last = builder.sub(length, ir.Constant(i64, LANES))
        rest = builder.mul(pairs, pair)
        a, a_index = update(a, a_index, *load(builder.select(builder.icmp_signed("<", rest, last), rest, last)))
        b, b_index = update(b, b_index, *load(last))
        best, best_index = _better(builder, a, a_index, b, b_index)
        width = LANES
        while width > 1:  # halve the lanes: 8 -> 4 -> 2 -> 1
            width //= 2
            upper = ir.Constant(indices, [width + k if k < width else k for k in range(LANES)])
            best, best_index = _better(builder, best, best_index, builder.shuffle_vector(best, best, upper),
                                       builder.shuffle_vector(best_index, best_index, upper))
        return builder.sext(builder.extract_element(best_index, ir.Constant(i32, 0)), i64)

    return signature, codegen


@njit(cache=True, inline="always")
def _first_min_scalar(costs):
    best = 0
    best_value = costs[0]
    for i in range(1, costs.shape[0]):
        if costs[i] < best_value:
            best_value = costs[i]
            best = i
    return best


def first_min(costs):
    """Index of the first smallest element of a non-empty 1-D float32 array (numba only).

    The scalar scan's result, bit for bit: ``best = 0``, then every element smaller than
    ``costs[best]`` becomes ``best`` (so a NaN never wins, and a NaN first element wins).
    """
    raise NotImplementedError("first_min is called from numba code only")


@overload(first_min, jit_options={"cache": True})
def _first_min_overload(costs):
    if not (isinstance(costs, types.Array) and costs.ndim == 1):
        return None
    if costs.dtype != types.float32 or costs.layout != "C":
        return lambda costs: _first_min_scalar(costs)

    def implementation(costs):
        # A NaN first element wins in the scalar scan; the vector code reads NaN as +inf.
        if costs.shape[0] < MIN_VECTOR_LENGTH or costs[0] != costs[0]:
            return _first_min_scalar(costs)
        return _first_min_vector(costs)
    return implementation

