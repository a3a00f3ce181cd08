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
"""

from __future__ import annotations

import llvmlite.ir as ir
from numba import types
from numba.core import cgutils, errors
from numba.extending import intrinsic, overload

__all__ = ["stack_array", "load", "store", "stream", "store_fence", "narrow"]


@intrinsic
def stack_array(typingctx, size, dtype):
    """A pointer to ``size`` (a compile-time integer) elements of ``dtype`` on the stack."""
    if not isinstance(size, types.IntegerLiteral):
        raise errors.RequireLiteralValue(size)
    elt = dtype.dtype

    def codegen(context, builder, sig, args):
        return cgutils.alloca_once(builder, context.get_data_type(elt), size=size.literal_value)

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
