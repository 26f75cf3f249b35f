"""Bit-for-bit comparison of nested tuples of floats (what compiled and interpreted code must agree on)."""

from __future__ import annotations


def bits(x: object) -> object:
    """``x`` with every float replaced by its exact hex form (tuples and NamedTuples recursively)."""
    if isinstance(x, float):
        return x.hex()
    if isinstance(x, tuple):
        return tuple(bits(v) for v in x)
    return x
