"""Read, summarise and plot the flight controller's ``.tlog`` files.

:func:`load_log` turns a log into a :class:`FlightLog` of numpy arrays in user-facing units and the
MAVLink NED convention (:mod:`ground.logs.load`, whose docstring says what the FC logs and the
conventions of :class:`FlightLog`: times in seconds since the first record, north/east/altitude-up
in metres, angles in degrees); :func:`summarize` reduces it to a JSON-ready dict of headline
numbers and :func:`print_summary` prints them (:mod:`ground.logs.summary`), with the flight
metrics of :func:`flight_metrics` (:mod:`ground.logs.metrics`: pure functions over arrays, also
for flights without a log; :func:`log_metrics` feeds them a log); :func:`plot_log`
writes PNG figures (:mod:`ground.logs.plots`). The CLI pieces (:func:`add_plot_arguments` /
:func:`plot_main` for ``smcpilot plot LOG`` and :func:`add_log_arguments` / :func:`log_main` for
``smcpilot log summary LOG``, :mod:`ground.logs.cli`) are wired into :mod:`lab.cli`.
:mod:`ground.logs.housekeeping` keeps a log directory small (``smcpilot log compress``,
``smcpilot log clean``, and the compression of older flights after ``sitl`` and ``demo``);
:mod:`ground.logs.progress` draws the progress line of a flight from its growing log.
"""

from __future__ import annotations

from ground.logs.cli import add_log_arguments, add_plot_arguments, log_main, plot_main
from ground.logs.load import CHANNELS, SIM_COMPONENT, FlightLog, LogError, LogEvent, TimeSeries, load_log
from ground.logs.metrics import MetricsError, flight_metrics
from ground.logs.plots import plot_log
from ground.logs.summary import DEFAULT_SETTLE_S, DEFAULT_SIGMA_WINDOW_S, log_metrics, print_summary, summarize

__all__ = [
    "LogError",
    "LogEvent",
    "TimeSeries",
    "FlightLog",
    "CHANNELS",
    "DEFAULT_SETTLE_S",
    "DEFAULT_SIGMA_WINDOW_S",
    "SIM_COMPONENT",
    "load_log",
    "summarize",
    "print_summary",
    "flight_metrics",
    "log_metrics",
    "MetricsError",
    "plot_log",
    "add_plot_arguments",
    "plot_main",
    "add_log_arguments",
    "log_main",
]
