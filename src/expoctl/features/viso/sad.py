"""Sum of absolute differences of two 32-byte descriptors, the matcher's innermost operation.

On x86-64 it compiles to two SSE2 `psadbw` instructions (as the original's SSE code does), ~10× faster than a byte
loop in numba; elsewhere it falls back to the byte loop. Both give the same integer.
"""

from __future__ import annotations

import platform

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

HAVE_PSADBW = platform.machine().lower() in ("x86_64", "amd64")


@intrinsic
def _psadbw_32(typingctx, addr_a, addr_b):
    """SAD of the 32 bytes at two integer addresses (two 16-byte psadbw, unaligned loads)."""
    sig = types.int64(addr_a, addr_b)

    def codegen(context, builder, signature, args):
        v16 = ir.VectorType(ir.IntType(8), 16)
        v2 = ir.VectorType(ir.IntType(64), 2)
        fn = builder.module.declare_intrinsic("llvm.x86.sse2.psad.bw", fnty=ir.FunctionType(v2, [v16, v16]))
        total = ir.Constant(ir.IntType(64), 0)
        for offset in (0, 16):
            pa = builder.inttoptr(builder.add(args[0], ir.Constant(args[0].type, offset)), v16.as_pointer())
            pb = builder.inttoptr(builder.add(args[1], ir.Constant(args[1].type, offset)), v16.as_pointer())
            r = builder.call(fn, [builder.load(pa, align=1), builder.load(pb, align=1)])
            total = builder.add(total, builder.extract_element(r, ir.Constant(ir.IntType(32), 0)))
            total = builder.add(total, builder.extract_element(r, ir.Constant(ir.IntType(32), 1)))
        return total

    return sig, codegen


@njit(cache=True)
def _sad32_loop(a, i, b, j):
    cost = 0
    for k in range(32):
        cost += abs(np.int32(a[i, k]) - np.int32(b[j, k]))
    return cost


if HAVE_PSADBW:

    @njit(cache=True)
    def sad32(a, i, b, j):
        """SAD of rows a[i] and b[j] of C-contiguous (N, 32) uint8 arrays (the caller guarantees layout and bounds)."""
        return _psadbw_32(a.ctypes.data + i * 32, b.ctypes.data + j * 32)

else:  # pragma: no cover - non-x86 platforms
    sad32 = _sad32_loop
