"""An example control-law plug-in for smcpilot: a PD law on feedback linearisation (``pd_feedback``).

Installed (``pip install examples/law-plugin``) it registers through the entry point
``[project.entry-points."smcpilot.laws"]`` and flies as ``--controller pd_feedback``; not installed,
the same file flies as ``--controller examples/law-plugin/smcpilot_pd_law/pd_law.py:PD_LAW``.
The walk-through is ``docs/your-own-law.md``.
"""

from smcpilot_pd_law.pd_law import PD_LAW, PdParams

__all__ = ["PD_LAW", "PdParams"]
