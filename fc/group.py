"""``python -m fc.group FILE``: several flight controllers in one process.

A swarm of K vehicles on a machine of a few cores (``smcpilot sitl --count K --fc-processes N``)
spends most of its time waking processes: the simulator sends K states a step, each wakes its own
FC process, which runs a few tens of microseconds and sleeps again, and K interpreters take turns
in the cores' caches. Here N processes fly the K flight controllers instead. Each flight controller
is exactly the one ``python -m fc ARGS`` would fly, built from the same arguments: its own simulator
and ground sockets, system id, parameters and parameter file, ``.tlog``, signing and watchdog. They
share the interpreter, the compiled pipeline (loaded once for all: ``--jit auto`` counts their
flights together) and the process's fate (a killed group is every one of its vehicles lost).

- **Lockstep** (:func:`fly`): one polling loop (``epoll``, :class:`smcpilot.udplink.readiness.Readiness`)
  calls each flight controller's lockstep steps as its sockets have something. A lockstep flight
  controller's log depends only on what its simulator sends it, so each log is the same, byte for
  byte, as its own process would write (tested).
- **Real time** (:func:`fly_realtime`): one loop calls each flight controller's real-time steps:
  its ticks at its deadlines, its ground-link work within its budget, what comes on its sockets.
  They keep their own wall clocks and watchdogs and share their deadlines (the same beat), so the
  process wakes once a period for all of them, and their ticks run one after the other.

FILE is JSON: a list of ``python -m fc`` argument lists (all lockstep or all real time). Each flight
controller's lines (``FC_LISTENING``, ``FC_READY``, errors, ``FC_SUMMARY``) are printed as ``@I LINE``,
I its index in FILE; lines of the process itself have no prefix. The exit code is the first non-zero
one of the flight controllers, else 0; a file that cannot be read, or mixes lockstep and real-time
flight controllers: one line, exit 2, nothing started.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import math
import os
import select
import signal
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TextIO

from fc.app import EXIT_CONFIG, EXIT_OK, FlightControllerApp
from fc.cli import build_app
from smcpilot.errors import RateMismatchError, WatchdogError
from smcpilot.udplink.readiness import Readiness

_yield = getattr(os, "sched_yield", lambda: None)

#: the ground link's acknowledgements, parameter lists, probes and watchdogs of every flight
#: controller are seen to at least this often (wall s) while states keep coming.
BETWEEN_S = 0.01


class Prefixed:
    """A text stream that writes each line to ``stream`` as ``PREFIX LINE`` (one flight
    controller's output within the group's)."""

    def __init__(self, stream: TextIO, prefix: str) -> None:
        self.stream = stream
        self.prefix = prefix
        self._partial = ""

    def write(self, text: str) -> int:
        lines = (self._partial + text).split("\n")
        self._partial = lines.pop()
        for line in lines:
            self.stream.write(f"{self.prefix}{line}\n")
        return len(text)

    def flush(self) -> None:
        if self._partial:
            self.stream.write(f"{self.prefix}{self._partial}\n")
            self._partial = ""
        self.stream.flush()


def _argument_lists(path: Path) -> list[list[str]]:
    """FILE's argument lists (raises ValueError or OSError saying what is wrong)."""
    data = json.loads(path.read_text())
    if not isinstance(data, list) or not data or not all(isinstance(a, list) and all(isinstance(v, str) for v in a) for a in data):
        raise ValueError("expected a non-empty JSON list of argument lists (lists of strings)")
    if len({"--lockstep" in a for a in data}) > 1:
        raise ValueError("some flight controllers are lockstep and some real time: a group flies one kind")
    return data


def fly(apps: Sequence[FlightControllerApp]) -> int:
    """Fly ``apps`` (built, lockstep) in one loop until each has ended; the exit code."""
    mono = time.monotonic
    for app in apps:
        app.flights_per_process = len(apps)
    started: list[FlightControllerApp] = []
    finished: list[FlightControllerApp] = []
    codes: list[int] = []
    poller = Readiness()
    try:
        for app in apps:
            app.start(freeze_gc=False)
            started.append(app)
        gc.collect()  # (as one app's start does: the loop's objects are all made)
        gc.freeze()
        for app in apps:
            app.lockstep_begin()
        live = list(apps)
        owners: dict[int, tuple[FlightControllerApp, bool]] = {}
        last_between = mono()
        impaired: list[FlightControllerApp] = []
        # busy-poll this long after the last state before blocking (the FCs' --spin-s, the least of them)
        spin_s = min(a.spin_s for a in apps)
        last_state = mono()
        while live:
            if not owners:
                owners = {a.sim.fileno(): (a, True) for a in live}
                owners.update({a.gcs.fileno(): (a, False) for a in live if a.gcs is not None})
                # an impaired link holds datagrams back: its app looks at it on every turn (as its own loop
                # does), and the loop wakes when the first held one is due
                impaired = [a for a in live if a._impaired]
                poller.watch(list(owners))
            spinning = spin_s > 0.0 and mono() - last_state < spin_s
            wait_s = 0.0 if spinning else min(a.lockstep_wait_s() for a in impaired) if impaired else 0.1
            readable = poller.wait(wait_s)
            if spinning and not readable and not impaired:
                _yield()  # (let another process have this core if the machine is oversubscribed)
                continue
            ended = []
            turn = [owners[fd] for fd in readable]
            turn += [(a, True) for a in impaired]
            for app, is_sim in turn:
                if app._stop:
                    continue
                try:
                    if is_sim:
                        if app.lockstep_take(1):  # (one datagram: the poll says when there is more)
                            last_state = mono()
                    else:
                        app.lockstep_between(True)
                except (WatchdogError, RateMismatchError) as exc:
                    app.ended_by(exc)
                if app._stop:
                    ended.append(app)
            now = mono()
            if not readable or now - last_between >= BETWEEN_S:
                last_between = now
                for app in live:
                    if not app._stop:
                        try:
                            app.lockstep_between(False)
                        except (WatchdogError, RateMismatchError) as exc:
                            app.ended_by(exc)
                ended = [a for a in live if a._stop]  # (a signal's stop too)
            for app in ended:
                if app in live:
                    live.remove(app)
                    finished.append(app)
                    codes.append(app.finish())
                    owners = {}
    finally:  # whatever ended the loop: every log closed, every summary said
        poller.close()
        for app in apps:
            if app in finished:
                continue
            with contextlib.suppress(Exception):
                if app in started:
                    codes.append(app.finish())
                else:
                    app.close()
    return next((c for c in codes if c != EXIT_OK), EXIT_OK)


def fly_realtime(apps: Sequence[FlightControllerApp]) -> int:
    """Fly ``apps`` (built, real time) in one loop until each has ended; the exit code.

    Each flight controller keeps its own wall clock, watchdogs and ground-link budget (the steps
    of its own real-time loop, :meth:`FlightControllerApp.realtime_due` and the rest), and their
    deadlines keep one beat, spread over the period: of ``K`` flight controllers the ``i``-th ticks
    ``i / K`` of a period after the first (or at its ``--tick-phase``, which the launcher gives every FC
    of a swarm: the i-th of the swarm's K; the first to have its first state sets the beat). One
    process has one core: sixteen deadlines at the same instant would make the last FC wait for the
    fifteen ticks before it, every period (measured: docs/swarms.md), where spread out each ticks
    when due and the process sleeps between them. Of the FCs with something to read, the one due
    soonest is read first, and a deadline that falls due meanwhile is ticked before the others are
    read (they stay readable): a burst of states does not hold up the ticks due while it is read.
    """
    mono = time.monotonic
    n_apps = len(apps)
    for app in apps:
        app.flights_per_process = n_apps
    started: list[FlightControllerApp] = []
    finished: list[FlightControllerApp] = []
    codes: list[int] = []
    # this FC's place on the beat, in periods
    phases = {id(a): i / n_apps if a.tick_phase is None else a.tick_phase for i, a in enumerate(apps)}

    live: list[FlightControllerApp] = list(apps)
    waiting: list[FlightControllerApp] = list(apps)  # (no state yet: their loops have not begun)
    flying: list[FlightControllerApp] = []  # (in the order of apps)
    # the sockets to wait on and whose they are, while no FC has a ground link (else made
    # each turn: each one's ground socket is watched only while its budget lasts); None: make anew
    fixed: tuple[list[int], dict[int, FlightControllerApp]] | None = None
    grounded = any(a.gcs is not None for a in apps)  # (an FC's ground link is made before the loop, for good)

    def end(app: FlightControllerApp) -> None:
        nonlocal fixed
        live.remove(app)
        if app in waiting:
            waiting.remove(app)
        if app in flying:
            flying.remove(app)
        fixed = None
        finished.append(app)
        codes.append(app.finish())

    try:
        for app in apps:
            app.start(freeze_gc=False)
            started.append(app)
        gc.collect()
        gc.freeze()
        with contextlib.ExitStack() as timed:
            for app in apps:
                timed.enter_context(app._gc_pauses)
            start = last_first = mono()
            beat: float | None = None  # when the first FC's deadlines fall (the others' follow theirs)
            while live:
                now = mono()
                if flying:
                    first = min(flying, key=_deadline)
                    if first.rt_deadline <= now:
                        due = [first] if n_apps == 1 else sorted((a for a in flying if a.rt_deadline <= now), key=_deadline)
                        for app in due:
                            if app._stop:
                                continue
                            try:
                                if app.realtime_due(mono()):
                                    app._stop = True
                            except (WatchdogError, RateMismatchError) as exc:
                                app.ended_by(exc)
                        for app in [a for a in live if a._stop]:
                            end(app)
                        continue
                    worked = False
                    for app in flying:
                        # (without a ground link an FC has ground work only when something came on
                        # its simulator port from elsewhere; its sockets are the same either way)
                        if (app.gcs is not None or app.intake) and app.realtime_work(now):
                            worked = True
                    if worked:
                        continue
                    next_due = first.rt_deadline
                    wait_s = next_due - now
                else:
                    next_due = math.inf
                    wait_s = 0.1
                if fixed is None or grounded:
                    owners: dict[int, FlightControllerApp] = {}
                    for app in flying:
                        for fd in app.realtime_fds():
                            owners[fd] = app
                    for app in waiting:
                        for fd in app._fds():
                            owners[fd] = app
                    fixed = (list(owners), owners)
                fds, owners = fixed
                if waiting:
                    wait_s = min(wait_s, 0.1)
                # (select, not epoll: epoll's timeout counts whole milliseconds, a deadline needs finer)
                readable, _, _ = select.select(fds, (), (), max(0.0, wait_s))
                if not readable and not waiting:
                    continue
                now = mono()
                first_turn = bool(waiting) and (readable or now - last_first >= 0.1)
                if first_turn:
                    last_first = now
                ready = {owners[fd] for fd in readable}
                turn = [a for a in live if a in ready or (first_turn and a in waiting)]
                if flying and len(turn) > 1:  # those not begun first, then the one due soonest (its fresh state before its tick)
                    turn.sort(key=lambda a: -math.inf if a in waiting else a.rt_deadline)
                for app in turn:
                    mine = [fd for fd in readable if owners[fd] is app]
                    try:
                        if app in waiting:
                            app.realtime_wait_first(mine, now - start)
                            if app.state is not None and not app._stop:
                                period = app.cfg.period_s
                                if beat is None:
                                    beat = now + period - phases[id(app)] * period
                                app.realtime_begin(now, beat_deadline(now, beat, phases[id(app)], period))
                                waiting.remove(app)
                                flying[:] = [a for a in apps if a in live and a not in waiting]
                                fixed = None
                        else:
                            app.realtime_readable(mine)
                    except (WatchdogError, RateMismatchError) as exc:
                        app.ended_by(exc)
                    if next_due <= mono() and app not in waiting:
                        break  # a deadline first; the rest stays readable for the next turn, in deadline order
                for app in [a for a in live if a._stop]:
                    end(app)
    finally:  # whatever ended the loop: every log closed, every summary said
        for app in apps:
            if app in finished:
                continue
            with contextlib.suppress(Exception):
                if app in started:
                    codes.append(app.finish())
                else:
                    app.close()
    return next((c for c in codes if c != EXIT_OK), EXIT_OK)


def _deadline(app: FlightControllerApp) -> float:
    return app.rt_deadline


def beat_deadline(now_s: float, beat_s: float, phase: float, period_s: float) -> float:
    """The first deadline after ``now_s`` of a flight controller ``phase`` periods (0 <= phase < 1)
    after the beat: the deadlines ``beat_s + (phase + n) period_s`` for whole ``n`` (wall s)."""
    at = beat_s + phase * period_s
    return at + (math.floor((now_s - at) / period_s) + 1) * period_s


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m fc.group",
        description="Several flight controllers in one process (a swarm on few cores): lockstep or real time, in one loop;"
        " each is the one `python -m fc ARGS` flies, its lines printed as '@I LINE'.",
    )
    p.add_argument("file", type=Path, metavar="FILE", help="JSON: a list of `python -m fc` argument lists, all lockstep (--lockstep) or all real time")
    args = p.parse_args(argv)
    try:
        argvs = _argument_lists(args.file)
    except (OSError, ValueError) as exc:
        print(f"fc.group: error: {args.file}: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    apps: list[FlightControllerApp] = []
    for i, a in enumerate(argvs):
        out = Prefixed(sys.stdout, f"@{i} ")
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):  # type: ignore[type-var]
            app = build_app(a, out=out)  # type: ignore[arg-type]
            out.flush()
        if isinstance(app, int):
            for built in apps:
                built.close()
            return app
        apps.append(app)

    def stop_all(*_: object) -> None:
        for app in apps:
            app.request_stop()

    signal.signal(signal.SIGTERM, stop_all)
    signal.signal(signal.SIGINT, stop_all)
    return fly(apps) if apps[0].lockstep else fly_realtime(apps)


if __name__ == "__main__":
    sys.exit(main())
