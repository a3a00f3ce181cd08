"""Low-level building blocks of the batch kernels that numba does not offer directly.

* :func:`stack_array` -- scratch memory on the stack (``carray(stack_array(k, np.float64), shape)``).
  With a compile-time size and constant indices LLVM keeps it in registers, and it
  cannot alias the kernel's input or output, so values read from it are not reloaded
  after every store to ``out`` (a heap ``np.empty`` array is, and costs an allocation).
* :func:`load` / :func:`store` -- ``arr[j]`` of a C-contiguous 1-D view without numba's
  negative-index wrap-around (the kernels' flat indices are never negative).
* :func:`stream` -- a non-temporal store: the output goes to memory without first being
  read into the cache (a plain store reads the line first, so writing x costs twice its
  bytes of memory traffic).  For outputs much larger than the cache only; a
  :func:`store_fence` after the last one makes them visible to other threads.
* :func:`narrow` -- True at compile time when an array stores fewer bits than float64
  (float32), so the float64 kernels carry no float32-only code.
* :data:`vec8` values (eight tracks in one vector) and their operations -- see below.
"""

from __future__ import annotations

import llvmlite.ir as ir
from numba import types
from numba.core import cgutils, errors
from numba.extending import intrinsic, models, overload, register_model

__all__ = ["stack_array", "load", "store", "stream", "store_fence", "narrow", "vec8", "mask8", "LANES8", "vload",
           "vstore", "vstream", "vsplat", "vadd", "vsub", "vmul", "vmaxabs", "visnan", "mor", "many", "vselect",
           "transpose8", "address"]


@intrinsic
def stack_array(typingctx, size, dtype):
    """A pointer to ``size`` (a compile-time integer) elements of ``dtype`` on the stack, aligned
    to a cache line."""
    if not isinstance(size, types.IntegerLiteral):
        raise errors.RequireLiteralValue(size)
    elt = dtype.dtype

    def codegen(context, builder, sig, args):
        ptr = cgutils.alloca_once(builder, context.get_data_type(elt), size=size.literal_value)
        ptr.align = 64      # whole cache lines: a vector (64 bytes) never straddles two
        return ptr

    return types.CPointer(elt)(size, dtype), codegen


def _element_pointer(context, builder, arrty, arr, index):
    ary = context.make_array(arrty)(context, builder, arr)
    return builder.gep(ary.data, [index])


@intrinsic
def load(typingctx, arr, index):
    """``arr[index]`` (C-contiguous 1-D ``arr``, ``0 <= index < arr.size``), as float64."""
    def codegen(context, builder, sig, args):
        value = builder.load(_element_pointer(context, builder, sig.args[0], args[0], args[1]))
        return context.cast(builder, value, sig.args[0].dtype, types.float64)

    return types.float64(arr, index), codegen


def _store_codegen(nontemporal: bool):
    def codegen(context, builder, sig, args):
        ptr = _element_pointer(context, builder, sig.args[0], args[0], args[1])
        inst = builder.store(context.cast(builder, args[2], sig.args[2], sig.args[0].dtype), ptr)
        if nontemporal:
            inst.set_metadata("nontemporal", builder.module.add_metadata([ir.IntType(32)(1)]))
        return context.get_dummy_value()
    return codegen


@intrinsic
def store(typingctx, arr, index, value):
    """``arr[index] = value`` (C-contiguous 1-D ``arr``), converted to the array's dtype."""
    return types.void(arr, index, value), _store_codegen(False)


@intrinsic
def stream(typingctx, arr, index, value):
    """As :func:`store`, with a non-temporal (cache-bypassing) store."""
    return types.void(arr, index, value), _store_codegen(True)


@intrinsic
def store_fence(typingctx):
    """Order this thread's earlier (non-temporal) stores before its later memory operations."""
    def codegen(context, builder, sig, args):
        builder.fence("seq_cst")
        return context.get_dummy_value()

    return types.void(), codegen


def narrow(arr):  # pragma: no cover - replaced by the overload in compiled code
    """True when ``arr`` stores fewer bits than float64 (a compile-time constant in a kernel)."""
    return arr.dtype.itemsize < 8


@overload(narrow)
def _narrow(arr):
    flag = arr.dtype.bitwidth < 64
    return lambda arr: flag


# --- eight tracks in one vector -------------------------------------------------------------------
#
# ``Vec8`` is an LLVM <8 x double>: one value of eight tracks (lanes), in one AVX-512 register
# (two AVX2 or four SSE registers elsewhere: LLVM splits it).  numba has no vector type and its
# SLP vectorizer is off, so the generated kernels' vector path is written with these.  Their
# arithmetic is that of the scalar code lane by lane (separate multiply and add, no FMA), so a
# track's numbers do not depend on which path ran it.

class Vec8Type(types.Type):
    def __init__(self):
        super().__init__(name="Vec8")


class Mask8Type(types.Type):
    def __init__(self):
        super().__init__(name="Mask8")


vec8 = Vec8Type()
mask8 = Mask8Type()
LANES8 = 8
_F64X8 = ir.VectorType(ir.DoubleType(), LANES8)
_I1X8 = ir.VectorType(ir.IntType(1), LANES8)


@register_model(Vec8Type)
class _Vec8Model(models.PrimitiveModel):
    def __init__(self, dmm, fe_type):
        super().__init__(dmm, fe_type, _F64X8)


@register_model(Mask8Type)
class _Mask8Model(models.PrimitiveModel):
    def __init__(self, dmm, fe_type):
        super().__init__(dmm, fe_type, _I1X8)


def _vector_of(context, arrty):
    return ir.VectorType(context.get_data_type(arrty.dtype), LANES8)


@intrinsic
def vload(typingctx, arr, index):
    """``arr[index:index + 8]`` (C-contiguous 1-D float64 or float32 ``arr``) as float64 lanes."""
    def codegen(context, builder, sig, args):
        vt = _vector_of(context, sig.args[0])
        ptr = builder.bitcast(_element_pointer(context, builder, sig.args[0], args[0], args[1]), vt.as_pointer())
        value = builder.load(ptr, align=sig.args[0].dtype.bitwidth // 8)
        return value if vt == _F64X8 else builder.fpext(value, _F64X8)

    return vec8(arr, index), codegen


def _vstore_codegen(nontemporal: bool):
    def codegen(context, builder, sig, args):
        vt = _vector_of(context, sig.args[0])
        value = args[2] if vt == _F64X8 else builder.fptrunc(args[2], vt)
        ptr = builder.bitcast(_element_pointer(context, builder, sig.args[0], args[0], args[1]), vt.as_pointer())
        width = sig.args[0].dtype.bitwidth // 8
        inst = builder.store(value, ptr, align=width * LANES8 if nontemporal else width)
        if nontemporal:
            inst.set_metadata("nontemporal", builder.module.add_metadata([ir.IntType(32)(1)]))
        return context.get_dummy_value()
    return codegen


@intrinsic
def vstore(typingctx, arr, index, value):
    """``arr[index:index + 8] = value`` converted to the array's dtype."""
    return types.void(arr, index, value), _vstore_codegen(False)


@intrinsic
def vstream(typingctx, arr, index, value):
    """As :func:`vstore`, non-temporal; ``&arr[index]`` must be aligned to the 8 values' size
    (:data:`VECTOR_BYTES`): an unaligned address is a segmentation fault, not an error."""
    return types.void(arr, index, value), _vstore_codegen(True)


@intrinsic
def vsplat(typingctx, x):
    """The float64 ``x`` in every lane."""
    def codegen(context, builder, sig, args):
        x = context.cast(builder, args[0], sig.args[0], types.float64)
        v = builder.insert_element(ir.Constant(_F64X8, ir.Undefined), x, ir.IntType(32)(0))
        return builder.shuffle_vector(v, ir.Constant(_F64X8, ir.Undefined),
                                      ir.Constant(ir.VectorType(ir.IntType(32), LANES8), [0] * LANES8))

    return vec8(x), codegen


def _vector_binary(instruction: str):
    @intrinsic
    def op(typingctx, a, b):
        def codegen(context, builder, sig, args):
            return getattr(builder, instruction)(args[0], args[1])
        return vec8(a, b), codegen
    return op


vadd = _vector_binary("fadd")
vsub = _vector_binary("fsub")
vmul = _vector_binary("fmul")


@intrinsic
def vmaxabs(typingctx, big, value):
    """Lane by lane ``max(big, abs(value))`` as Python's max: ``abs(value)`` where it is greater."""
    def codegen(context, builder, sig, args):
        fabs = cgutils.get_or_insert_function(builder.module, ir.FunctionType(_F64X8, [_F64X8]), "llvm.fabs.v8f64")
        mag = builder.call(fabs, [args[1]])
        return builder.select(builder.fcmp_ordered(">", mag, args[0]), mag, args[0])

    return vec8(big, value), codegen


@intrinsic
def visnan(typingctx, a):
    """The lanes of ``a`` that are NaN."""
    def codegen(context, builder, sig, args):
        return builder.fcmp_unordered("uno", args[0], args[0])

    return mask8(a), codegen


@intrinsic
def mor(typingctx, a, b):
    def codegen(context, builder, sig, args):
        return builder.or_(args[0], args[1])

    return mask8(a, b), codegen


@intrinsic
def many(typingctx, a):
    """True when some lane of the mask is set."""
    def codegen(context, builder, sig, args):
        bits = builder.bitcast(args[0], ir.IntType(LANES8))
        return builder.icmp_unsigned("!=", bits, ir.IntType(LANES8)(0))

    return types.boolean(a), codegen


@intrinsic
def vselect(typingctx, mask, a, b):
    """``a`` in the lanes of ``mask``, ``b`` elsewhere."""
    def codegen(context, builder, sig, args):
        return builder.select(args[0], args[1], args[2])

    return vec8(mask, a, b), codegen


@intrinsic
def transpose8(typingctx, rows):
    """The 8 x 8 transpose of a tuple of eight vectors: element i of vector j becomes element j
    of vector i (three rounds of two-input shuffles: 24 shuffle instructions with AVX-512)."""
    if not (isinstance(rows, types.UniTuple) and rows.count == LANES8 and rows.dtype == vec8):
        raise errors.TypingError("transpose8: expected a tuple of eight Vec8")

    def codegen(context, builder, sig, args):
        def shuffle(a, b, mask):
            return builder.shuffle_vector(a, b, ir.Constant(ir.VectorType(ir.IntType(32), LANES8), mask))

        v = [builder.extract_value(args[0], i) for i in range(LANES8)]
        for pairs, lo, hi in (
                ([(0, 1), (2, 3), (4, 5), (6, 7)], [0, 8, 2, 10, 4, 12, 6, 14], [1, 9, 3, 11, 5, 13, 7, 15]),
                ([(0, 2), (1, 3), (4, 6), (5, 7)], [0, 1, 8, 9, 4, 5, 12, 13], [2, 3, 10, 11, 6, 7, 14, 15]),
                ([(0, 4), (1, 5), (2, 6), (3, 7)], [0, 1, 2, 3, 8, 9, 10, 11], [4, 5, 6, 7, 12, 13, 14, 15])):
            w = list(v)
            for a, b in pairs:
                w[a], w[b] = shuffle(v[a], v[b], lo), shuffle(v[a], v[b], hi)
            v = w
        out = cgutils.get_null_value(context.get_value_type(sig.return_type))
        for i in range(LANES8):
            out = builder.insert_value(out, v[i], i)
        return out

    return types.UniTuple(vec8, LANES8)(rows), codegen


@intrinsic
def address(typingctx, arr):
    """The address of ``arr``'s first element, as an integer (to check alignment)."""
    def codegen(context, builder, sig, args):
        ary = context.make_array(sig.args[0])(context, builder, args[0])
        return builder.ptrtoint(ary.data, ir.IntType(64))

    return types.int64(arr), codegen
