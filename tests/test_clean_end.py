"""Every run ends clean: both processes exit by themselves with code 0 at the end of a run, in real
time as in lockstep; the launcher reports a process it had to stop as a failure of the run."""

from __future__ import annotations

import signal
from pathlib import Path

import pytest

from ground.sitl import END_GRACE_S, Sitl, SitlError, SitlOptions


@pytest.mark.parametrize("lockstep", [False, True], ids=["real-time", "lockstep"])
def test_both_processes_exit_by_themselves_with_code_0(tmp_path: Path, lockstep: bool) -> None:
    for k in range(2):
        opts = SitlOptions.of(tlog=tmp_path / f"r{k}.tlog", log_dir=tmp_path, gcs=None, lockstep=lockstep, duration_s=1.0)
        with Sitl(opts) as sitl:
            assert sitl.wait(timeout_s=60) == 0
        assert sitl.fc is not None and sitl.sim is not None
        assert (sitl.fc.proc.returncode, sitl.sim.proc.returncode) == (0, 0), "exited by themselves, not stopped"


@pytest.mark.slow
def test_a_process_that_does_not_end_by_itself_is_a_failed_run(tmp_path: Path) -> None:
    """The FC stopped (SIGSTOP) when the simulator ends: it cannot exit by itself; the launcher
    waits END_GRACE_S, stops it, and says so instead of reporting success."""
    opts = SitlOptions.of(tlog=tmp_path / "s.tlog", log_dir=tmp_path, gcs=None, lockstep=False, duration_s=1.0)
    with Sitl(opts) as sitl:
        assert sitl.fc is not None
        sitl.fc.proc.send_signal(signal.SIGSTOP)
        with pytest.raises(SitlError, match=rf"fc did not exit by itself within {END_GRACE_S:g} s of the run's end"):
            sitl.wait(timeout_s=60)
