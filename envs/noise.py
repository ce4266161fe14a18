"""numpy's sensor-noise stream in compiled code: ``Generator(PCG64).standard_normal`` for the vector env's parallel step.

The single env draws its sensor noise in blocks of ``NOISE_BLOCK`` control periods with
``np_random.standard_normal((NOISE_BLOCK, cols))``. The vector env keeps each sub-env's generator state as four
uint64 words (:func:`pcg_words`) and draws the same blocks inside its parallel step with :func:`fill_normals`:
numpy's PCG64 (XSL-RR 128/64: ``state = state * M + inc``, output ``rotr(hi ^ lo, hi >> 58)``) and numpy's
ziggurat ``random_standard_normal`` (its tables as numba ships them), so the numbers are numpy's bit for bit
(tests/test_envs_vector.py draws 10^5 of them against numpy, and the vector env equals the single env). The state
goes back to the sub-env's ``np.random.Generator`` before a reset draws its episode from it
(:func:`set_pcg_words`), so every draw of a sub-env comes from one stream in the single env's order.

Without numba, :func:`fill_normals` is numpy itself (a PCG64 set to the words).
"""
from __future__ import annotations

import numpy as np

from etb_gym.jit import HAVE_NUMBA

_M64 = (1 << 64) - 1


def pcg_words(rng: np.random.Generator, out: np.ndarray) -> np.ndarray:
    """Write the PCG64 state of ``rng`` into ``out`` (4 uint64: state high, low, increment high, low)."""
    st = rng.bit_generator.state
    if st["bit_generator"] != "PCG64":
        raise TypeError(f"a sub-env generator is {st['bit_generator']}: the vector env's noise expects PCG64 "
                        "(gymnasium.utils.seeding.np_random)")
    s, inc = st["state"]["state"], st["state"]["inc"]
    out[0], out[1], out[2], out[3] = s >> 64, s & _M64, inc >> 64, inc & _M64
    return out


def set_pcg_words(rng: np.random.Generator, words: np.ndarray) -> None:
    """Set the PCG64 state of ``rng`` to ``words`` (as :func:`pcg_words` writes them; the 32-bit buffer kept)."""
    st = rng.bit_generator.state
    st["state"] = {"state": (int(words[0]) << 64) | int(words[1]), "inc": (int(words[2]) << 64) | int(words[3])}
    rng.bit_generator.state = st


def fill_normals(out, words):
    """Fill the 2-D array ``out`` (C order) with standard normals drawn from the PCG64 state ``words`` (advanced
    in place): what ``np.random.Generator(PCG64 at words).standard_normal(out=out)`` draws."""
    bg = np.random.PCG64()
    st = bg.state
    st["state"] = {"state": (int(words[0]) << 64) | int(words[1]), "inc": (int(words[2]) << 64) | int(words[3])}
    bg.state = st
    np.random.Generator(bg).standard_normal(out=out)
    pcg_words(np.random.Generator(bg), words)


if HAVE_NUMBA:   # the compiled fill_normals: numpy's algorithms, ported
    import math

    from llvmlite import ir
    from numba import types
    from numba.extending import intrinsic, overload, register_jitable
    from numba.np.random import _constants as _zig    # numpy's ziggurat tables (numba's port of numpy's Generator)

    _KI, _WI, _FI = _zig.ki_double, _zig.wi_double, _zig.fi_double
    _NOR_R, _NOR_INV_R = _zig.ziggurat_nor_r, _zig.ziggurat_nor_inv_r
    _MUL_HI, _MUL_LO = np.uint64(2549297995355413924), np.uint64(4865540595714422341)   # PCG's 128-bit multiplier

    @intrinsic
    def _lcg128(typingctx, hi, lo, mhi, mlo, ihi, ilo):
        """(hi:lo) * (mhi:mlo) + (ihi:ilo) mod 2^128, as (high, low) words: PCG64's state step."""
        sig = types.UniTuple(types.uint64, 2)(types.uint64, types.uint64, types.uint64, types.uint64, types.uint64,
                                               types.uint64)

        def codegen(context, builder, signature, args):
            i128 = ir.IntType(128)
            sixty_four = ir.Constant(i128, 64)

            def wide(h, low):
                return builder.or_(builder.shl(builder.zext(h, i128), sixty_four), builder.zext(low, i128))

            r = builder.add(builder.mul(wide(args[0], args[1]), wide(args[2], args[3])), wide(args[4], args[5]))
            words = [builder.trunc(builder.lshr(r, sixty_four), ir.IntType(64)), builder.trunc(r, ir.IntType(64))]
            return context.make_tuple(builder, signature.return_type, words)

        return sig, codegen

    @register_jitable
    def _next_uint64(w):
        hi, lo = _lcg128(w[0], w[1], _MUL_HI, _MUL_LO, w[2], w[3])
        w[0] = hi
        w[1] = lo
        v = hi ^ lo
        rot = hi >> np.uint64(58)
        return (v >> rot) | (v << ((np.uint64(64) - rot) & np.uint64(63)))

    @register_jitable
    def _next_double(w):
        return np.float64(_next_uint64(w) >> np.uint64(11)) * (1.0 / 9007199254740992.0)

    @register_jitable
    def _standard_normal(w):
        """numpy's random_standard_normal (distributions.c), line by line."""
        while True:
            r = _next_uint64(w)
            idx = np.int64(r & np.uint64(0xff))
            r >>= np.uint64(8)
            sign = r & np.uint64(1)
            rabs = (r >> np.uint64(1)) & np.uint64(0x000fffffffffffff)
            x = np.float64(rabs) * _WI[idx]
            if sign:
                x = -x
            if rabs < _KI[idx]:
                return x
            if idx == 0:
                while True:
                    xx = -_NOR_INV_R * math.log1p(-_next_double(w))
                    yy = -math.log1p(-_next_double(w))
                    if yy + yy > xx * xx:
                        return -(_NOR_R + xx) if (rabs >> np.uint64(8)) & np.uint64(1) else _NOR_R + xx
            elif (_FI[idx - 1] - _FI[idx]) * _next_double(w) + _FI[idx] < math.exp(-0.5 * x * x):
                return x

    @overload(fill_normals, jit_options={"cache": True})
    def _fill_normals_compiled(out, words):
        def impl(out, words):
            flat = out.reshape(out.size)
            for k in range(flat.size):
                flat[k] = _standard_normal(words)
        return impl
