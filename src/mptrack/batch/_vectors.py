"""Eight float64 lanes in one value, for the batch kernels' time blocks (:mod:`._kernels`).

numba has no vector type and leaves LLVM's SLP vectorizer off; its loop vectorizer does vectorize a
time block written as loops, but with run-time alias checks and spills that made it no faster than
the scalar recursion (measured: 19 ms vs 18 ms per 10^7 model-B updates on one core).  ``Vec8`` is an
LLVM ``<8 x double>`` (one AVX-512 register; LLVM splits it into two AVX2 or four SSE registers
elsewhere) with the few operations the blocks need.  The arrays these read and write are 1-D and
C-contiguous, indexed from 0 without numba's negative-index wrap-around (the kernels' indices are
never negative).
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils, errors
from numba.extending import intrinsic, models, overload, register_model

__all__ = [
    "fma",
    "stack_buffer",
    "source",
    "vadd",
    "vbcast",
    "vec8",
    "vfma",
    "vlane",
    "vload",
    "vmul",
    "vfinite",
    "vsplat",
    "vstore",
    "vstore2",
    "vstore_axes",
    "vstore_pairs",
    "vsum",
]

_WIDTH = 8
_F64X8 = ir.VectorType(ir.DoubleType(), _WIDTH)
_I32 = ir.IntType(32)


class _Vec8Type(types.Type):
    def __init__(self):
        super().__init__(name="Vec8")


vec8 = _Vec8Type()


@register_model(_Vec8Type)
class _Vec8Model(models.PrimitiveModel):
    def __init__(self, dmm, fe_type):
        super().__init__(dmm, fe_type, _F64X8)


def _element(context, builder, arrty, arr, index):
    return builder.gep(context.make_array(arrty)(context, builder, arr).data, [index])


def _splat(builder, x, vt):
    v = builder.insert_element(ir.Constant(vt, ir.Undefined), x, _I32(0))
    return builder.shuffle_vector(v, ir.Constant(vt, ir.Undefined), ir.Constant(ir.VectorType(_I32, _WIDTH),
                                                                                  [0] * _WIDTH))


@intrinsic
def vload(typingctx, arr, index):
    """``arr[index:index + 8]`` as float64 (float32 is widened)."""
    def codegen(context, builder, sig, args):
        arrty = sig.args[0]
        vt = ir.VectorType(context.get_data_type(arrty.dtype), _WIDTH)
        ptr = builder.bitcast(_element(context, builder, arrty, *args), vt.as_pointer())
        v = builder.load(ptr, align=arrty.dtype.bitwidth // 8)
        return v if vt == _F64X8 else builder.fpext(v, _F64X8)

    return vec8(arr, index), codegen


@intrinsic
def vstore(typingctx, arr, index, v):
    """``arr[index:index + 8] = v`` (a float64 array)."""
    def codegen(context, builder, sig, args):
        ptr = builder.bitcast(_element(context, builder, sig.args[0], args[0], args[1]), _F64X8.as_pointer())
        builder.store(args[2], ptr, align=8)
        return context.get_dummy_value()

    return types.void(arr, index, v), codegen


@intrinsic
def vbcast(typingctx, arr, index):
    """``arr[index]`` in every lane (a float64 array: the blocks read float32 measurements after
    :func:`source` widened them)."""
    if arr.dtype != types.float64:
        raise errors.TypingError(f"vbcast: expected a float64 array, got {arr}")

    def codegen(context, builder, sig, args):
        return _splat(builder, builder.load(_element(context, builder, sig.args[0], *args)), _F64X8)

    return vec8(arr, index), codegen


@intrinsic
def vsplat(typingctx, x):
    """The float64 ``x`` in every lane."""
    def codegen(context, builder, sig, args):
        return _splat(builder, context.cast(builder, args[0], sig.args[0], types.float64), _F64X8)

    return vec8(x), codegen


def _fma_function(builder, ty, name):
    return cgutils.get_or_insert_function(builder.module, ir.FunctionType(ty, [ty] * 3), name)


@intrinsic
def vfma(typingctx, a, b, c):
    """``a * b + c`` lane by lane, rounded once."""
    def codegen(context, builder, sig, args):
        return builder.call(_fma_function(builder, _F64X8, "llvm.fma.v8f64"), list(args))

    return vec8(a, b, c), codegen


@intrinsic
def fma(typingctx, a, b, c):
    """``a * b + c`` of three float64, rounded once (as :func:`vfma` in each lane)."""
    def codegen(context, builder, sig, args):
        return builder.call(_fma_function(builder, ir.DoubleType(), "llvm.fma.f64"), list(args))

    return types.float64(types.float64, types.float64, types.float64), codegen


@intrinsic
def vmul(typingctx, a, b):
    def codegen(context, builder, sig, args):
        return builder.fmul(*args)

    return vec8(a, b), codegen


@intrinsic
def vadd(typingctx, a, b):
    def codegen(context, builder, sig, args):
        return builder.fadd(*args)

    return vec8(a, b), codegen


@intrinsic
def vlane(typingctx, v, i):
    """Lane ``i`` of ``v``."""
    def codegen(context, builder, sig, args):
        return builder.extract_element(*args)

    return types.float64(v, i), codegen


@intrinsic
def vsum(typingctx, v):
    """The sum of the eight lanes (in lane order)."""
    def codegen(context, builder, sig, args):
        s = builder.extract_element(args[0], _I32(0))
        for i in range(1, _WIDTH):
            s = builder.fadd(s, builder.extract_element(args[0], _I32(i)))
        return s

    return types.float64(v), codegen


def _as_stored(context, builder, dtype, vectors):
    """``vectors`` converted to an array's dtype (float32: narrowed), and their sum as stored, widened
    to float64 (float32: added in float32): the stores' return value, finite when every value stored
    is finite, and when one is not, not finite either (an infinity or a NaN stays one in a sum; finite
    values large enough to sum to an infinity are a false alarm)."""
    elt = context.get_data_type(dtype)
    if elt != ir.DoubleType():
        vectors = [builder.fptrunc(v, ir.VectorType(elt, _WIDTH)) for v in vectors]
    total = vectors[0]
    for v in vectors[1:]:
        total = builder.fadd(total, v)
    return vectors, total if total.type == _F64X8 else builder.fpext(total, _F64X8)


@intrinsic
def vstore2(typingctx, arr, index, a, b):
    """``arr[index:index + 16] = a, b`` converted to the array's dtype (float32: one 64-byte store).
    Returns the sum of the two halves as stored (:func:`_as_stored`)."""
    def codegen(context, builder, sig, args):
        arrty = sig.args[0]
        ptr = _element(context, builder, arrty, args[0], args[1])
        (lo, hi), total = _as_stored(context, builder, arrty.dtype, [args[2], args[3]])
        if arrty.dtype == types.float64:
            parts = [(ptr, lo), (builder.gep(ptr, [ir.IntType(64)(_WIDTH)]), hi)]
        else:
            both = builder.shuffle_vector(lo, hi, ir.Constant(ir.VectorType(_I32, 2 * _WIDTH), list(range(2 * _WIDTH))))
            parts = [(ptr, both)]
        for p, value in parts:
            builder.store(value, builder.bitcast(p, value.type.as_pointer()), align=arrty.dtype.bitwidth // 8)
        return total

    return vec8(arr, index, a, b), codegen


@intrinsic
def stack_buffer(typingctx, size):
    """A pointer to ``size`` (a compile-time integer) float64 on the stack (``numba.carray(p, size)``
    makes it an array): scratch memory without an allocation, which LLVM knows no other array shares.
    It lives as long as the function that calls this (the kernel's own body, never a helper that
    returns it)."""
    if not isinstance(size, types.IntegerLiteral):
        raise errors.RequireLiteralValue(size)

    def codegen(context, builder, sig, args):
        ptr = cgutils.alloca_once(builder, ir.DoubleType(), size=size.literal_value)
        ptr.align = 64
        return ptr

    return types.CPointer(types.float64)(size), codegen


@intrinsic
def vstore_pairs(typingctx, arr, index, stride, a, b):
    """The eight pairs (a[0:2], a[2:4], .., b[6:8]) to ``arr[index + i stride : .. + 2]``, i = 0..7,
    converted to the array's dtype: the (position, velocity) of eight steps of one axis into rows that
    hold several axes.  Returns the sum of the two halves as stored, as :func:`vstore2` does."""
    def codegen(context, builder, sig, args):
        arrty = sig.args[0]
        base = _element(context, builder, arrty, args[0], args[1])
        stride = context.cast(builder, args[2], sig.args[2], types.int64)
        halves, total = _as_stored(context, builder, arrty.dtype, [args[3], args[4]])
        pair = ir.VectorType(context.get_data_type(arrty.dtype), 2)
        for h, half in enumerate(halves):
            for i in range(_WIDTH // 2):
                value = builder.shuffle_vector(half, ir.Constant(half.type, ir.Undefined),
                                               ir.Constant(ir.VectorType(_I32, 2), [2 * i, 2 * i + 1]))
                offset = builder.mul(stride, ir.IntType(64)(h * _WIDTH // 2 + i))
                ptr = builder.bitcast(builder.gep(base, [offset]), pair.as_pointer())
                builder.store(value, ptr, align=arrty.dtype.bitwidth // 8)
        return total

    return vec8(arr, index, stride, a, b), codegen


def _interleave(builder, halves, k):
    """The 2k vectors of eight steps of a row of k axes as they lie in ``out`` (step j: position,
    velocity of axis 0, then of axis 1, ..), from each axis's two halves (``halves[2a]``: its steps
    0..3, ``halves[2a + 1]``: 4..7, as :func:`vstore2` takes them); each vector gathers its lanes from
    the halves it needs with two-vector shuffles."""
    width = ir.VectorType(_I32, _WIDTH)
    vectors = []
    for m in range(2 * k):
        lanes = []                      # (half, lane) of each value of vector m
        for f in range(_WIDTH * m, _WIDTH * (m + 1)):
            step, r = divmod(f, 2 * k)
            axis, c = divmod(r, 2)
            lanes.append((2 * axis + step // 4, 2 * (step % 4) + c))
        sources = list(dict.fromkeys(h for h, _ in lanes))
        first, second = sources[0], sources[1] if len(sources) > 1 else None
        order = [lane if h == first else _WIDTH + lane if h == second else 0 for h, lane in lanes]
        v = builder.shuffle_vector(halves[first], halves[first] if second is None else halves[second],
                                   ir.Constant(width, order))
        for h in sources[2:]:           # each further half fills its lanes, the others stay
            order = [_WIDTH + lane if g == h else i for i, (g, lane) in enumerate(lanes)]
            v = builder.shuffle_vector(v, halves[h], ir.Constant(width, order))
        vectors.append(v)
    return vectors


@intrinsic
def vstore_axes(typingctx, arr, index, halves):
    """The eight steps of a row of k axes, given as each axis's two halves (a tuple of 2k vectors as
    :func:`vstore2` takes one axis's), to ``arr[index:index + 16 k]`` interleaved as the row holds them,
    converted to the array's dtype: whole-vector stores where :func:`vstore_pairs` stores 8 k pairs.
    Returns the sum of the values as stored (:func:`_as_stored`)."""
    if not (isinstance(halves, types.UniTuple) and halves.dtype == vec8 and halves.count % 2 == 0):
        raise errors.TypingError(f"vstore_axes: expected an even tuple of Vec8, got {halves}")

    def codegen(context, builder, sig, args):
        arrty = sig.args[0]
        k = sig.args[2].count // 2
        halves = [builder.extract_value(args[2], i) for i in range(2 * k)]
        vectors, total = _as_stored(context, builder, arrty.dtype, _interleave(builder, halves, k))
        base = _element(context, builder, arrty, args[0], args[1])
        for m, v in enumerate(vectors):
            ptr = builder.gep(base, [ir.IntType(64)(_WIDTH * m)])
            builder.store(v, builder.bitcast(ptr, v.type.as_pointer()), align=arrty.dtype.bitwidth // 8)
        return total

    return vec8(arr, index, halves), codegen


@intrinsic
def vfinite(typingctx, v):
    """True when every lane of ``v`` is finite."""
    def codegen(context, builder, sig, args):
        zero = builder.fmul(args[0], ir.Constant(_F64X8, [0.0] * _WIDTH))      # NaN where v is not finite
        bad = builder.fcmp_unordered("uno", zero, zero)
        return builder.icmp_unsigned("==", builder.bitcast(bad, ir.IntType(_WIDTH)), ir.IntType(_WIDTH)(0))

    return types.boolean(v), codegen


def source(zf, base, k, n, buf):  # pragma: no cover - replaced by the overload in compiled code
    """The measurements of n blocks of rows of k values from zf[base] as float64 for the time blocks,
    and how many of those blocks come before the first with a NaN or an infinity (a sum of finite
    values that overflows counts as one: its rows then run the scalar steps, which give the same
    numbers): (zf, base, clean) for float64; float32 is widened into ``buf`` (whole vectors, up to that
    block), (buf, 0, clean)."""
    raise NotImplementedError


@overload(source)
def _source(zf, base, k, n, buf):
    if zf.dtype.bitwidth == 64:
        def scan(zf, base, k, n, buf):
            for i in range(n):
                s = vload(zf, base + 8 * k * i)
                for c in range(1, k):
                    s = vadd(s, vload(zf, base + 8 * (k * i + c)))
                if not vfinite(s):
                    return zf, base, i
            return zf, base, n

        return scan

    def widen(zf, base, k, n, buf):
        for i in range(n):
            s = vload(zf, base + 8 * k * i)
            vstore(buf, 8 * k * i, s)
            for c in range(1, k):
                v = vload(zf, base + 8 * (k * i + c))
                vstore(buf, 8 * (k * i + c), v)
                s = vadd(s, v)
            if not vfinite(s):
                return buf, 0, i
        return buf, 0, n

    return widen
