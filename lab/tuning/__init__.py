"""Tuning measurements on the flight core and the rigid-body plant, in-process (docs/baselines.md).

- :mod:`lab.tuning.bandwidth`: each law's closed-loop roll bandwidth, step rise time and
  noise-to-motor RMS at hover (``python -m lab.tuning.bandwidth``);
- :mod:`lab.tuning.stiffness`: the outer position loop's RMS error in gusts and steady offset in
  constant wind (``python -m lab.tuning.stiffness``).
"""
