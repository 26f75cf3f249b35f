"""The compiled in-process flight: a numba kernel flies the plain ticks, Python the eventful ones.

:mod:`lab.fast.kernel` (the kernel), :mod:`lab.fast.flight` (the driver :func:`lab.runner.simulate`
calls), :mod:`lab.fast.mt` (CPython's random streams for the kernel), :mod:`lab.fast.bench`
(``smcpilot bench fast``). docs/performance.md has the design and the figures.
"""
