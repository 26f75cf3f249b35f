"""In-process work on the flight core: the scenario runner, the paper reproduction, benchmarks.

``lab`` may combine :mod:`fc`, :mod:`sim_bridge` and :mod:`smcpilot` in one process (no MAVLink,
no UDP); nothing else imports ``lab``. :mod:`lab.cli` is the ``smcpilot`` console entry point: it
dispatches lazily to the subcommand modules of ``ground`` and ``lab``.
"""
