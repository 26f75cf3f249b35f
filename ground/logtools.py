"""The log tools under their first name: they live in :mod:`ground.logs` now
(:mod:`~ground.logs.load`, :mod:`~ground.logs.summary`, :mod:`~ground.logs.plots`,
:mod:`~ground.logs.cli`). This module re-exports their public names (``__all__`` as before, and
``SIM_COMPONENT``), so ``from ground import logtools`` and ``from ground.logtools import
load_log`` keep working.
"""

from __future__ import annotations

from ground.logs.cli import add_log_arguments, add_plot_arguments, log_main, plot_main
from ground.logs.load import CHANNELS, FlightLog, LogError, LogEvent, TimeSeries, load_log
from ground.logs.load import SIM_COMPONENT as SIM_COMPONENT
from ground.logs.plots import plot_log
from ground.logs.summary import DEFAULT_SETTLE_S, DEFAULT_SIGMA_WINDOW_S, print_summary, summarize

__all__ = [
    "LogError",
    "LogEvent",
    "TimeSeries",
    "FlightLog",
    "CHANNELS",
    "DEFAULT_SETTLE_S",
    "DEFAULT_SIGMA_WINDOW_S",
    "load_log",
    "summarize",
    "print_summary",
    "plot_log",
    "add_plot_arguments",
    "plot_main",
    "add_log_arguments",
    "log_main",
]
