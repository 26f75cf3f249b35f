"""CPython's ``random.Random`` (MT19937 and its ``random()``/``gauss()``) in the pure style, on arrays.

The simulator's random streams are ``random.Random`` objects (gusts, sensor noise:
:mod:`sim_bridge.environment`). A compiled flight draws from the *same* streams: the driver
exports a generator's state into two arrays (:func:`mt_export`), the compiled kernel draws with
:func:`mt_gauss` (the same numbers, bit for bit, as ``rng.gauss``), and the driver writes the
state back (:func:`mt_import`), so CPython and compiled flights of one seed are the same flight.

State arrays: ``mt`` (int64, 625): the 624 words of MT19937 and the position; ``gs`` (float64,
2): whether a second Gaussian is kept (``gauss_next`` is not None) and its value.
"""

from __future__ import annotations

import math
import random

import numpy as np

_N = 624
_M = 397
_MATRIX_A = 0x9908B0DF
_UPPER = 0x80000000
_LOWER = 0x7FFFFFFF
_TWO_PI = 2.0 * math.pi
_log = math.log
_sqrt = math.sqrt
_cos = math.cos
_sin = math.sin


def mt_export(rng: random.Random) -> tuple[np.ndarray, np.ndarray]:
    """The state of ``rng`` as the arrays the pure functions take."""
    version, internal, gauss_next = rng.getstate()
    mt = np.array(internal, dtype=np.int64)
    gs = np.array([0.0 if gauss_next is None else 1.0, 0.0 if gauss_next is None else gauss_next])
    return mt, gs


def mt_import(rng: random.Random, mt: np.ndarray, gs: np.ndarray) -> None:
    """Set ``rng`` to the state held in the arrays."""
    rng.setstate((rng.VERSION, tuple(mt.tolist()), float(gs[1]) if gs[0] != 0.0 else None))


def _twist(mt: np.ndarray) -> None:
    for kk in range(_N - _M):
        y = (mt[kk] & _UPPER) | (mt[kk + 1] & _LOWER)
        mt[kk] = mt[kk + _M] ^ (y >> 1) ^ (_MATRIX_A if y & 1 else 0)
    for kk in range(_N - _M, _N - 1):
        y = (mt[kk] & _UPPER) | (mt[kk + 1] & _LOWER)
        mt[kk] = mt[kk + (_M - _N)] ^ (y >> 1) ^ (_MATRIX_A if y & 1 else 0)
    y = (mt[_N - 1] & _UPPER) | (mt[0] & _LOWER)
    mt[_N - 1] = mt[_M - 1] ^ (y >> 1) ^ (_MATRIX_A if y & 1 else 0)
    mt[_N] = 0


def mt_uint32(mt: np.ndarray) -> int:
    """The next 32-bit output (CPython's ``genrand_uint32``)."""
    if mt[_N] >= _N:
        _twist(mt)
    i = mt[_N]
    y = mt[i]
    mt[_N] = i + 1
    y ^= y >> 11
    y ^= (y << 7) & 0x9D2C5680
    y ^= (y << 15) & 0xEFC60000
    y ^= y >> 18
    return y


def mt_random(mt: np.ndarray) -> float:
    """``random.random()``: a float in [0, 1) with 53 random bits."""
    a = mt_uint32(mt) >> 5
    b = mt_uint32(mt) >> 6
    return (a * 67108864.0 + b) * (1.0 / 9007199254740992.0)


def mt_gauss(mt: np.ndarray, gs: np.ndarray, mu: float, sigma: float) -> float:
    """``random.gauss(mu, sigma)`` (CPython's method: a pair per two uniforms, the second kept)."""
    if gs[0] != 0.0:
        z = gs[1]
        gs[0] = 0.0
        gs[1] = 0.0
    else:
        x2pi = mt_random(mt) * _TWO_PI
        g2rad = _sqrt(-2.0 * _log(1.0 - mt_random(mt)))
        z = _cos(x2pi) * g2rad
        gs[0] = 1.0
        gs[1] = _sin(x2pi) * g2rad
    return mu + z * sigma


def mt_gauss_fill(mt: np.ndarray, gs: np.ndarray, out: np.ndarray, n: int) -> None:
    """``n`` calls of ``random.gauss`` at once: their unit deviates ``z`` into ``out[0:n]`` in
    draw order (``gauss(mu, sigma)`` is ``mu + z * sigma``; the stream ends as after the n calls).

    The same numbers as :func:`mt_gauss`, drawn in one function without a call per word or per
    draw: compiled, every call that is handed an array pays for its reference count (two atomic
    operations a call), which cost more than the Mersenne Twister itself when paid per draw.
    """
    j = 0
    while j < n:
        if gs[0] != 0.0:
            out[j] = gs[1]
            gs[0] = 0.0
            gs[1] = 0.0
            j += 1
            continue
        # two random() = four words: a, b of the first, a, b of the second
        a = 0
        u = 0.0
        v = 0.0
        for h in range(4):
            if mt[_N] >= _N:
                _twist(mt)
            i = mt[_N]
            y = mt[i]
            mt[_N] = i + 1
            y ^= y >> 11
            y ^= (y << 7) & 0x9D2C5680
            y ^= (y << 15) & 0xEFC60000
            y ^= y >> 18
            if h == 0 or h == 2:
                a = y >> 5
            elif h == 1:
                u = (a * 67108864.0 + (y >> 6)) * (1.0 / 9007199254740992.0)
            else:
                v = (a * 67108864.0 + (y >> 6)) * (1.0 / 9007199254740992.0)
        x2pi = u * _TWO_PI
        g2rad = _sqrt(-2.0 * _log(1.0 - v))
        out[j] = _cos(x2pi) * g2rad
        gs[0] = 1.0
        gs[1] = _sin(x2pi) * g2rad
        j += 1


#: what the compiled kernel calls (compiled as one set with it).
MT_FUNCTIONS = (_twist, mt_uint32, mt_random, mt_gauss, mt_gauss_fill)
