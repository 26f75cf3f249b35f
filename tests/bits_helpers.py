"""Bit-for-bit comparison of nested tuples of floats (what compiled and interpreted code must agree on),
and the mark of a test that needs the compiled paths."""

from __future__ import annotations

import pytest

from smcpilot.jit import jit_enabled

#: a test of a compiled path: skipped where numba is off (``SMCPILOT_JIT=0``) or not installed.
needs_jit = pytest.mark.skipif(not jit_enabled(say=False), reason="compiled paths are off here (SMCPILOT_JIT=0 or no numba)")


def bits(x: object) -> object:
    """``x`` with every float replaced by its exact hex form (tuples and NamedTuples recursively)."""
    if isinstance(x, float):
        return x.hex()
    if isinstance(x, tuple):
        return tuple(bits(v) for v in x)
    return x
