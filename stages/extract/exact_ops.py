"""Compiled forms of numpy's, BLAS's and OpenCV's arithmetic, to the bit, for the kernels of
the perspective chain (issue 9): where a kernel replaces a numpy expression, a BLAS product or
an OpenCV call, its results must stay those of the code it replaced (the features are
compared to stored references), and these are how those libraries round on this build
(see tests/test_perspective_kernels.py):

- ``fused_multiply_add`` (float64) and ``fused_multiply_add32`` (float32): a * b + c rounded
  once (LLVM's fma). numpy's dot of two 2-vectors (BLAS) is fused_multiply_add(u[1], v[1],
  u[0] * v[0]), each row of a matrix-vector product of two or more rows
  fused_multiply_add(m[k, 0], v[0], m[k, 1] * v[1]), and each entry of a matrix product of
  two or more rows with three columns (``rel @ m.T``) fused_multiply_add(r2, m2,
  fused_multiply_add(r1, m1, r0 m0));
- ``remap_at``: cv2.remap of a float32 image at one point, INTER_LINEAR with a constant
  border.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic


def _fma_typing(numba_type, llvm_type, a, b, c):
    """(signature, codegen) of LLVM's fma in one float type (``numba_type``, ``llvm_type``),
    its arguments cast to it; None unless all three are floats."""
    if not all(isinstance(t, types.Float) for t in (a, b, c)):
        return None
    sig = numba_type(numba_type, numba_type, numba_type)

    def codegen(context, builder, signature, args):
        args = [context.cast(builder, v, t, numba_type)
                for v, t in zip(args, signature.args)]
        fn = builder.module.declare_intrinsic("llvm.fma", [llvm_type],
                                              ir.FunctionType(llvm_type, [llvm_type] * 3))
        return builder.call(fn, args)

    return sig, codegen


@intrinsic
def fused_multiply_add32(typingctx, a, b, c):
    """a * b + c in float32 rounded once (LLVM's fma): OpenCV's bilinear remap of float32
    images interpolates with it (see crossings._remap_sample)."""
    return _fma_typing(types.float32, ir.FloatType(), a, b, c)


@intrinsic
def fused_multiply_add(typingctx, a, b, c):
    """a * b + c rounded once (LLVM's fma), for the compiled kernels: numpy's dot of two
    2-vectors (``u @ v``, BLAS) is fused_multiply_add(u[1], v[1], u[0] * v[0]), and each row
    of a matrix-vector product ``m @ v`` of two or more rows fused_multiply_add(m[k, 0],
    v[0], m[k, 1] * v[1]); a sum of the products is not these to the bit."""
    return _fma_typing(types.float64, ir.DoubleType(), a, b, c)


@njit(cache=True, nogil=True)
def remap_at(image, x, y, border):
    """cv2.remap of a float32 ``image`` at one point (x, y) in float32, INTER_LINEAR with
    BORDER_CONSTANT ``border`` (float32), to the bit: OpenCV interpolates along the row, then
    across, each step one fused multiply-add in float32."""
    h, w = image.shape
    fx, fy = np.floor(x), np.floor(y)
    ix, iy = int(fx), int(fy)
    ax, ay = x - fx, y - fy
    in0, in1 = 0 <= iy < h, 0 <= iy + 1 < h
    left, right = 0 <= ix < w, 0 <= ix + 1 < w
    p00 = image[iy, ix] if in0 and left else border
    p01 = image[iy, ix + 1] if in0 and right else border
    p10 = image[iy + 1, ix] if in1 and left else border
    p11 = image[iy + 1, ix + 1] if in1 and right else border
    r0 = fused_multiply_add32(p01 - p00, ax, p00)
    r1 = fused_multiply_add32(p11 - p10, ax, p10)
    return fused_multiply_add32(r1 - r0, ay, r0)
