"""Hot inner loops written as vector code, eight float32 lanes at a time.

LLVM leaves three hot loops of a decode scalar, and they are written here as plain LLVM IR
vectors (no target-specific intrinsics; the results are the scalar loops', bit for bit):

* :func:`first_min`, the index of a row's first minimum: every winner-take-all
  (:func:`stereobudget.aggregate.subpixel_winner`) scans a pixel's cost layers for it, and
  three tree walks of a Hybrid decode do it once per pixel each.  A float minimum
  carried with its index does not vectorise without fast-math flags, and fast math
  would change which of two equal costs wins.  Here each of eight lanes keeps the
  smallest value it has seen and where it saw it; the lanes are merged by value, then
  by index.
* :func:`skewed_block_copy`, the right view's costs read along the left view's
  diagonals (:mod:`stereobudget.aggregate._pair_volumes`): a strided read that LLVM turns into one
  scalar load per element.  Here eight source rows' vectors are blended into eight
  output rows.
* :func:`periodic_corner_sum`, the Sparse fill's weights of every layer from the few
  channels they repeat (:func:`stereobudget.fill.slice_pixel`): tiled element by
  element, they made the vector loads that read them wait.

:func:`blend_rows_first_min` fuses the first with the downward pass of a tree walk.

:func:`fixed_path_step` is one step of a semi-global path in 16-bit integers, sixteen
layers at a time (OpenCV's representation): numba widens every small-integer operation
to 64 bits, and the scalar form of the same step ran at half the float32 loop's speed.
"""

from __future__ import annotations

import math

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


def _best_lane_index(builder, value, index):
    """The index (i64) of the best of the 8 lanes' (value, index) candidates (:func:`_better`)."""
    i32 = ir.IntType(32)
    width = LANES
    while width > 1:  # halve the lanes: 8 -> 4 -> 2 -> 1
        width //= 2
        upper = ir.Constant(ir.VectorType(i32, LANES), [width + k if k < width else k for k in range(LANES)])
        value, index = _better(builder, value, index, builder.shuffle_vector(value, value, upper),
                               builder.shuffle_vector(index, index, upper))
    return builder.sext(builder.extract_element(index, ir.Constant(i32, 0)), ir.IntType(64))


def _broadcast(builder, scalar, vector_type):
    """``scalar`` in every lane of a ``vector_type`` value."""
    i32 = ir.IntType(32)
    vector = builder.insert_element(ir.Constant(vector_type, ir.Undefined), scalar, ir.Constant(i32, 0))
    return builder.shuffle_vector(vector, vector, ir.Constant(ir.VectorType(i32, vector_type.count),
                                                              [0] * vector_type.count))


def _is_array(value, ndim, dtype=types.float32):
    """Whether the numba type ``value`` is a C-contiguous ``ndim``-D array of ``dtype``
    (the intrinsics address their elements from the data pointer)."""
    return isinstance(value, types.Array) and value.ndim == ndim and value.dtype == dtype and value.layout == "C"


def _counted_loop(builder, name, first, stop, state, body):
    """``for k in range(first, stop): state = body(k, *state)`` as IR (i64 ``k``); returns the final state."""
    i64 = ir.IntType(64)
    entry = builder.block
    loop = builder.append_basic_block(name + ".loop")
    done = builder.append_basic_block(name + ".done")
    builder.cbranch(builder.icmp_signed("<", first, stop), loop, done)
    builder.position_at_end(loop)
    counter = builder.phi(i64)
    current = [builder.phi(value.type) for value in state]
    following = body(counter, *current)
    next_counter = builder.add(counter, ir.Constant(i64, 1))
    loop_end = builder.block
    counter.add_incoming(first, entry)
    counter.add_incoming(next_counter, loop_end)
    for phi, initial, value in zip(current, state, following):
        phi.add_incoming(initial, entry)
        phi.add_incoming(value, loop_end)
    builder.cbranch(builder.icmp_signed("<", next_counter, stop), loop, done)
    builder.position_at_end(done)
    final = []
    for initial, value in zip(state, following):
        phi = builder.phi(initial.type)
        phi.add_incoming(initial, entry)
        phi.add_incoming(value, loop_end)
        final.append(phi)
    return final


@intrinsic
def _first_min_vector(typingctx, array):
    """Index of the first minimum of a C-contiguous float32 row of >= 16 elements whose
    first element is not NaN (NaN elements never win, as in the scalar scan)."""
    if not _is_array(array, 1):
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
            return values, builder.add(_broadcast(builder, builder.trunc(offset, i32), indices), lane_numbers)

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
        return _best_lane_index(builder, *_better(builder, a, a_index, b, b_index))

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


@intrinsic
def skewed_block_copy(typingctx, source, source_start, row_length, target, target_starts):
    """``target[target_starts[r] + j] = source[source_start + (r + j) * row_length + j]`` for r, j < 8.

    Eight rows of a diagonal read: output row ``r`` takes element ``j`` from source row
    ``r + j``.  The 15 source vectors are loaded once and each output vector is blended
    from eight of them, instead of 64 scalar loads at strided addresses.  ``source`` and
    ``target`` are C-contiguous 1-D float32 arrays and ``target_starts`` 8 int64; no index
    is checked.
    """
    if not (_is_array(source, 1) and _is_array(target, 1) and _is_array(target_starts, 1, types.int64)
            and isinstance(source_start, types.Integer) and isinstance(row_length, types.Integer)):
        return None
    signature = types.void(source, source_start, row_length, target, target_starts)

    def codegen(context, builder, sig, args):
        f32, i32, i64 = ir.FloatType(), ir.IntType(32), ir.IntType(64)
        vector = ir.VectorType(f32, LANES)
        source_view = context.make_array(sig.args[0])(context, builder, args[0])
        target_view = context.make_array(sig.args[3])(context, builder, args[3])
        starts_view = context.make_array(sig.args[4])(context, builder, args[4])
        first = context.cast(builder, args[1], sig.args[1], types.int64)
        step = context.cast(builder, args[2], sig.args[2], types.int64)
        source_data = builder.bitcast(source_view.data, f32.as_pointer())
        target_data = builder.bitcast(target_view.data, f32.as_pointer())
        starts_data = builder.bitcast(starts_view.data, i64.as_pointer())
        rows = []
        for k in range(2 * LANES - 1):
            offset = builder.add(first, builder.mul(step, ir.Constant(i64, k)))
            rows.append(builder.load(builder.bitcast(builder.gep(source_data, [offset]), vector.as_pointer()),
                                     align=4))
        for r in range(LANES):
            out = rows[r]
            for j in range(1, LANES):
                # Lane j from source row r + j, every other lane kept.
                mask = [LANES + k if k == j else k for k in range(LANES)]
                out = builder.shuffle_vector(out, rows[r + j], ir.Constant(ir.VectorType(i32, LANES), mask))
            start = builder.load(builder.gep(starts_data, [ir.Constant(i64, r)]))
            builder.store(out, builder.bitcast(builder.gep(target_data, [start]), vector.as_pointer()), align=4)
        return context.get_dummy_value()

    return signature, codegen


@intrinsic
def blend_rows_first_min(typingctx, row, above, similarity, keep, competing):
    """``row[d] = similarity * above[d] + keep * row[d]`` for every d, and the index of the
    first minimum of the new ``row[:competing]`` (:func:`first_min`'s, for a row whose
    first element is not NaN).

    The down pass of a tree walk and its winner-take-all in one loop: each new vector is
    compared while it is still in a register.  ``row`` and ``above`` are C-contiguous
    float32 rows of the same length, a multiple of 8 (not checked), with
    ``1 <= competing <= len(row)``.  The blend is the scalar loop's arithmetic (two
    products and a sum, each rounded to float32), bit for bit.
    """
    if not (_is_array(row, 1) and _is_array(above, 1) and similarity == types.float32 and keep == types.float32
            and isinstance(competing, types.Integer)):
        return None
    signature = types.int64(row, above, similarity, keep, competing)

    def codegen(context, builder, sig, args):
        f32, i32, i64 = ir.FloatType(), ir.IntType(32), ir.IntType(64)
        vector, indices = ir.VectorType(f32, LANES), ir.VectorType(i32, LANES)
        row_view = context.make_array(sig.args[0])(context, builder, args[0])
        above_view = context.make_array(sig.args[1])(context, builder, args[1])
        length = cgutils.unpack_tuple(builder, row_view.shape, 1)[0]
        row_data = builder.bitcast(row_view.data, vector.as_pointer())
        above_data = builder.bitcast(above_view.data, vector.as_pointer())
        competing = context.cast(builder, args[4], sig.args[4], types.int64)
        limit = _broadcast(builder, builder.trunc(competing, i32), indices)
        similarity_vector, keep_vector = _broadcast(builder, args[2], vector), _broadcast(builder, args[3], vector)
        infinity = ir.Constant(vector, [float("inf")] * LANES)
        lane_numbers = ir.Constant(indices, list(range(LANES)))
        lanes = ir.Constant(i64, LANES)

        def block(index, best, best_index, padded):
            """Blend vector ``index`` of the rows; fold it into (best, best_index).

            A NaN never compares smaller, so it never wins without being replaced; lanes
            past ``competing`` (only in a ``padded`` block) are kept out by the mask.
            """
            above_values = builder.load(builder.gep(above_data, [index]), align=4)
            pointer = builder.gep(row_data, [index])
            values = builder.fadd(builder.fmul(similarity_vector, above_values),
                                  builder.fmul(keep_vector, builder.load(pointer, align=4)))
            builder.store(values, pointer, align=4)
            block_indices = builder.add(_broadcast(builder, builder.trunc(builder.mul(index, lanes), i32), indices),
                                        lane_numbers)
            smaller = builder.fcmp_ordered("<", values, best)
            if padded:
                smaller = builder.and_(smaller, builder.icmp_signed("<", block_indices, limit))
            return builder.select(smaller, values, best), builder.select(smaller, block_indices, best_index)

        blocks = builder.sdiv(length, lanes)
        # Blocks whose lanes all compete go in pairs to two accumulators, A and B (two
        # independent chains of compares); the rest, with the padding mask, to A.  Each
        # lane of each accumulator sees its indices in increasing order, so a strict <
        # keeps the first of equal values; A and B are merged by value, then by index.
        pairs = builder.sdiv(competing, ir.Constant(i64, 2 * LANES))
        start = (infinity, lane_numbers, infinity, lane_numbers)

        def pair_body(counter, a, a_index, b, b_index):
            first = builder.mul(counter, ir.Constant(i64, 2))
            a, a_index = block(first, a, a_index, False)
            b, b_index = block(builder.add(first, ir.Constant(i64, 1)), b, b_index, False)
            return a, a_index, b, b_index

        a, a_index, b, b_index = _counted_loop(builder, "blend.pairs", ir.Constant(i64, 0), pairs, start, pair_body)
        a, a_index = _counted_loop(builder, "blend.rest", builder.mul(pairs, ir.Constant(i64, 2)), blocks, (a, a_index),
                                  lambda counter, best, best_index: block(counter, best, best_index, True))
        # Lanes that never saw a usable value hold (+inf, lane number): an all-+inf row
        # still ties to index 0, as in the scalar scan.
        return _best_lane_index(builder, *_better(builder, a, a_index, b, b_index))

    return signature, codegen


#: Most base channels :func:`periodic_corner_sum` takes (one 16-lane vector per corner).
MAX_PERIOD_CHANNELS = 2 * LANES
#: Readable floats that must follow the last row given to :func:`periodic_corner_sum`.
PERIOD_READ_PAST = MAX_PERIOD_CHANNELS


def period_lanes(channels: int) -> int:
    """Lanes of one period of :func:`periodic_corner_sum`'s output: ``lcm(channels, 8)``."""
    return channels * LANES // math.gcd(channels, LANES)


#: Longest period of :func:`periodic_corner_sum` (15 channels: 120 lanes); a target of
#: ``count + MAX_PERIOD_LANES`` floats holds what it writes for any channel count.
MAX_PERIOD_LANES = max(period_lanes(b) for b in range(1, MAX_PERIOD_CHANNELS + 1))


@intrinsic
def periodic_corner_sum(typingctx, rows, corner_index, corner_weight, count, target, eps):
    """``target[i] = sum over the 8 corners c of corner_weight[c] * rows[corner_index[c], i % B]``
    for ``i`` below ``count`` rounded up to whole periods (at least one); returns the
    period, ``lcm(B, 8)`` lanes, negated when one of the sums that layers below ``count``
    use (channels ``< min(B, count)``) is ``<= eps``, or 0 (nothing written) when
    ``B = rows.shape[1]`` is not in ``1 .. 16``.

    The weight grid's B channels repeat along the layers (:class:`stereobudget.fill.SliceGrids`).
    Summed as scalars and tiled into the layers element by element, each vector the
    division then read waited for the scalar stores it spans to reach the cache.  Here
    each corner's channels are one 16-lane load, the 8 products are summed in registers
    (corner order, each product and sum rounded to float32: the scalar loop's sum, bit
    for bit), and every output vector is a shuffle of the sum, stored whole.  The slice
    needs to know whether a layer's weight is light (its fallback); compared here, in
    the register that holds them, the B sums need no loads of their own.

    ``corner_index`` (8,) int64 and ``corner_weight`` (8,) float32 are C-contiguous;
    ``rows`` (cells, B) float32 C-contiguous must be followed in memory by
    :data:`PERIOD_READ_PAST` readable floats (the loads read past a row's B channels;
    those lanes are never used), and ``target`` must hold ``count`` rounded up to a
    multiple of ``lcm(B, 8)`` floats.  No index is checked.
    """
    if not (_is_array(rows, 2) and _is_array(corner_index, 1, types.int64) and _is_array(corner_weight, 1)
            and isinstance(count, types.Integer) and _is_array(target, 1) and isinstance(eps, types.Float)):
        return None
    signature = types.int64(rows, corner_index, corner_weight, count, target, eps)

    def codegen(context, builder, sig, args):
        f32, i32, i64 = ir.FloatType(), ir.IntType(32), ir.IntType(64)
        wide, vector = ir.VectorType(f32, MAX_PERIOD_CHANNELS), ir.VectorType(f32, LANES)
        rows_view = context.make_array(sig.args[0])(context, builder, args[0])
        index_view = context.make_array(sig.args[1])(context, builder, args[1])
        weight_view = context.make_array(sig.args[2])(context, builder, args[2])
        target_view = context.make_array(sig.args[4])(context, builder, args[4])
        channels = cgutils.unpack_tuple(builder, rows_view.shape, 2)[1]
        count = context.cast(builder, args[3], sig.args[3], types.int64)
        rows_data = builder.bitcast(rows_view.data, f32.as_pointer())
        index_data = builder.bitcast(index_view.data, i64.as_pointer())
        weight_data = builder.bitcast(weight_view.data, f32.as_pointer())
        target_data = builder.bitcast(target_view.data, f32.as_pointer())

        supported = builder.and_(builder.icmp_signed(">=", channels, ir.Constant(i64, 1)),
                                 builder.icmp_signed("<=", channels, ir.Constant(i64, MAX_PERIOD_CHANNELS)))
        entry = builder.block
        compute = builder.append_basic_block("period.sum")
        done = builder.append_basic_block("period.done")
        builder.cbranch(supported, compute, done)

        builder.position_at_end(compute)
        total = None
        for corner in range(8):
            row = builder.load(builder.gep(index_data, [ir.Constant(i64, corner)]))
            start = builder.gep(rows_data, [builder.mul(row, channels)])
            values = builder.load(builder.bitcast(start, wide.as_pointer()), align=4)
            weight = _broadcast(builder, builder.load(builder.gep(weight_data, [ir.Constant(i64, corner)])), wide)
            product = builder.fmul(weight, values)
            total = product if total is None else builder.fadd(total, product)

        # Whether a channel of the layers below ``count`` is light: lanes < min(B, count) <= eps.
        threshold = _broadcast(builder, context.cast(builder, args[5], sig.args[5], types.float32), wide)
        light_lanes = builder.zext(builder.bitcast(builder.fcmp_ordered("<=", total, threshold),
                                                   ir.IntType(MAX_PERIOD_CHANNELS)), i32)
        used = builder.trunc(builder.select(builder.icmp_signed("<", channels, count), channels, count), i32)
        used_mask = builder.sub(builder.shl(ir.Constant(i32, 1), used), ir.Constant(i32, 1))
        light = builder.icmp_unsigned("!=", builder.and_(light_lanes, used_mask), ir.Constant(i32, 0))

        one = ir.Constant(i64, 1)
        # One case per channel count: its period's shuffles are constants.
        cases_end = builder.append_basic_block("period.cases_end")
        switch = builder.switch(channels, cases_end)
        periods = []
        for b in range(1, MAX_PERIOD_CHANNELS + 1):
            case = builder.append_basic_block(f"period.b{b}")
            switch.add_case(ir.Constant(i64, b), case)
            builder.position_at_end(case)
            lanes = period_lanes(b)
            shuffled = [builder.shuffle_vector(total, total, ir.Constant(ir.VectorType(i32, LANES),
                                                                         [(k * LANES + j) % b for j in range(LANES)]))
                        for k in range(lanes // LANES)]
            # Whole periods until ``count`` is covered (at least one).
            whole = builder.sdiv(builder.add(count, ir.Constant(i64, lanes - 1)), ir.Constant(i64, lanes))
            whole = builder.select(builder.icmp_signed("<", whole, one), one, whole)

            def store_period(period, shuffled=shuffled, lanes=lanes):
                first = builder.mul(period, ir.Constant(i64, lanes))
                for k, value in enumerate(shuffled):
                    at = builder.gep(target_data, [builder.add(first, ir.Constant(i64, k * LANES))])
                    builder.store(value, builder.bitcast(at, vector.as_pointer()), align=4)
                return ()

            _counted_loop(builder, f"period.b{b}", ir.Constant(i64, 0), whole, (), store_period)
            periods.append((builder.select(light, ir.Constant(i64, -lanes), ir.Constant(i64, lanes)), builder.block))
            builder.branch(done)
        builder.position_at_end(cases_end)  # not reached: channels is in 1 .. 16 here
        builder.branch(done)

        builder.position_at_end(done)
        result = builder.phi(i64)
        result.add_incoming(ir.Constant(i64, 0), entry)
        result.add_incoming(ir.Constant(i64, 0), cases_end)
        for value, block in periods:
            result.add_incoming(value, block)
        return result

    return signature, codegen


#: Lanes of one 16-bit vector of :func:`fixed_path_step`.
FIXED_LANES = 16


def _fixed_cost_vector(builder, data, offset, scale, is_float):
    """Cost elements [offset, offset + 16) as 16-bit path costs: ``uint16(cost * scale + 0.5)``,
    each product and sum rounded to float32 (the scalar :func:`stereobudget.aggregate` quantisation)."""
    f32 = ir.FloatType()
    wide = ir.VectorType(f32, FIXED_LANES)
    if is_float:
        values = builder.load(builder.bitcast(builder.gep(data, [offset]), wide.as_pointer()), align=4)
    else:
        raw = builder.load(builder.bitcast(builder.gep(data, [offset]),
                                           ir.VectorType(ir.IntType(8), FIXED_LANES).as_pointer()), align=1)
        values = builder.uitofp(raw, wide)
    half = ir.Constant(wide, [0.5] * FIXED_LANES)
    scaled = builder.fadd(builder.fmul(values, _broadcast(builder, scale, wide)), half)
    # Through signed 32 bits (one vector conversion; a direct unsigned 16-bit one is scalarised).
    whole = builder.fptosi(scaled, ir.VectorType(ir.IntType(32), FIXED_LANES))
    return builder.trunc(whole, ir.VectorType(ir.IntType(16), FIXED_LANES))


@intrinsic
def fixed_path_step(typingctx, cost, scale, previous, out, previous_min, p1, jump):
    """The inner layers of one semi-global path step in 16-bit integers; returns their minimum.

    For ``0 < d < D - 1`` (``D = len(cost) >= 18``, not checked)::

        out[d] = c(d) + min(previous[d], min(previous[d - 1], previous[d + 1]) + p1, jump) - previous_min

    with ``c(d) = uint16(cost[d] * scale + 0.5)`` (float32 arithmetic), every sum modulo
    2**16: the caller keeps every value below that.  The layers go sixteen at a time, the
    last vector overlapping the one before where ``D - 2`` is not a multiple of 16 (a layer
    computed twice gets the same value).  ``cost`` is a C-contiguous float32 or uint8 row,
    ``previous`` and ``out`` C-contiguous uint16 rows of its length; ``scale`` float32,
    the rest uint16.  The first and last layers are the caller's.
    """
    if not (isinstance(cost, types.Array) and cost.ndim == 1 and cost.layout == "C"
            and cost.dtype in (types.float32, types.uint8) and scale == types.float32
            and _is_array(previous, 1, types.uint16) and _is_array(out, 1, types.uint16)
            and previous_min == types.uint16 and p1 == types.uint16 and jump == types.uint16):
        return None
    signature = types.uint16(cost, scale, previous, out, previous_min, p1, jump)
    is_float = cost.dtype == types.float32

    def codegen(context, builder, sig, args):
        i16, i32, i64 = ir.IntType(16), ir.IntType(32), ir.IntType(64)
        vector = ir.VectorType(i16, FIXED_LANES)
        cost_view = context.make_array(sig.args[0])(context, builder, args[0])
        previous_view = context.make_array(sig.args[2])(context, builder, args[2])
        out_view = context.make_array(sig.args[3])(context, builder, args[3])
        length = cgutils.unpack_tuple(builder, cost_view.shape, 1)[0]
        cost_data = builder.bitcast(cost_view.data, (ir.FloatType() if is_float else ir.IntType(8)).as_pointer())
        previous_data = builder.bitcast(previous_view.data, i16.as_pointer())
        out_data = builder.bitcast(out_view.data, i16.as_pointer())
        previous_min, p1, jump = (_broadcast(builder, value, vector) for value in args[4:7])
        one = ir.Constant(i64, 1)

        def unsigned_min(a, b):
            return builder.select(builder.icmp_unsigned("<", a, b), a, b)

        def load(offset):
            return builder.load(builder.bitcast(builder.gep(previous_data, [offset]), vector.as_pointer()), align=2)

        def step(offset, smallest):
            neighbours = unsigned_min(load(builder.sub(offset, one)), load(builder.add(offset, one)))
            best = unsigned_min(unsigned_min(load(offset), builder.add(neighbours, p1)), jump)
            value = builder.sub(builder.add(_fixed_cost_vector(builder, cost_data, offset, args[1], is_float), best),
                                previous_min)
            builder.store(value, builder.bitcast(builder.gep(out_data, [offset]), vector.as_pointer()), align=2)
            return unsigned_min(smallest, value)

        lanes = ir.Constant(i64, FIXED_LANES)
        inner = builder.sub(length, ir.Constant(i64, 2))
        whole = builder.sdiv(inner, lanes)
        smallest = ir.Constant(vector, [0xFFFF] * FIXED_LANES)
        smallest, = _counted_loop(builder, "fixed.step", ir.Constant(i64, 0), whole, (smallest,),
                                  lambda k, smallest: (step(builder.add(builder.mul(k, lanes), one), smallest),))
        # The last inner vector ends at layer D - 2; where the whole ones stopped short of
        # it, it overlaps them.
        smallest = step(builder.sub(length, ir.Constant(i64, FIXED_LANES + 1)), smallest)
        width = FIXED_LANES
        while width > 1:  # halve the lanes: 16 -> 8 -> 4 -> 2 -> 1
            width //= 2
            upper = ir.Constant(ir.VectorType(i32, FIXED_LANES),
                                [width + k if k < width else k for k in range(FIXED_LANES)])
            smallest = unsigned_min(smallest, builder.shuffle_vector(smallest, smallest, upper))
        return builder.extract_element(smallest, ir.Constant(i32, 0))

    return signature, codegen
