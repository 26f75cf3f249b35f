"""rotorpy as the simulator, our flight controller as its PX4: an independent plant on PX4's API.

:func:`fly` runs rotorpy's PX4 vehicle (``rotorpy.vehicles.px4_multirotor.PX4Multirotor``: it
listens on TCP, sends ``HIL_STATE_QUATERNION`` and ``HIL_SENSOR`` every step and flies the
``HIL_ACTUATOR_CONTROLS`` it gets back, ``controls[i] * rotor_speed_max`` as rotor i's speed) with
``python -m fc --sim px4:tcp:127.0.0.1:PORT`` as the autopilot, the vehicle our FC flies being
rotorpy's mapped by :func:`smcpilot.rotorpy_vehicle.vehicle_from_rotorpy`.

What :class:`LockstepPx4Multirotor` changes in rotorpy 3.0.0's vehicle, and why:

- **lockstep**: rotorpy waits 10 ms for the answer and otherwise flies the step with its rotors
  commanded to 0 (and the late answer then lands on the next step, one step behind for good);
  on a loaded machine that is a crash that says nothing about either side. Here each step waits
  (up to ``answer_timeout_s``) for the answer stamped with the state's ``time_usec``, as PX4's
  own lockstep does;
- **the body rates** of ``HIL_STATE_QUATERNION``: rotorpy sends its FLU rates there (its
  ``HIL_SENSOR`` gyro is converted to FRD); MAVLink's message and PX4 define them in FRD (PX4 only
  uses the message as ground truth, so it never shows). Here they are sent in FRD;
- **a motor fault**: rotor ``k`` gives ``efficiency`` of its thrust (and drag torque) from
  ``at_s`` on, as our plant's ``[[fault]] kind = "motor"`` does: its commanded speed times
  ``sqrt(efficiency)``;
- the integrator: RK45 (rotorpy's vehicle defaults to Radau, about 4 times slower per step here;
  the dynamics are not stiff at a 4 ms step).

rotorpy is an optional dependency (the ``test`` extra installs it); this module imports it only
when :func:`fly` runs.
"""

from __future__ import annotations

import json
import math
import socket
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from smcpilot.protocol import SIM_COMPONENT_ID
from smcpilot.rotorpy_vehicle import rotorpy_frame, vehicle_from_rotorpy

#: a step's answer waited for at most this long (wall s) before the flight is given up.
ANSWER_TIMEOUT_S = 10.0


@dataclass(frozen=True)
class MotorFault:
    """Rotor ``rotor`` (1..4, rotorpy's numbering = PX4's motor order) at ``efficiency`` of its thrust from ``at_s``."""

    rotor: int
    efficiency: float
    at_s: float


@dataclass
class RotorpyFlight:
    """What :func:`fly` gives back: the FC's log, its exit code and summary, rotorpy's truth."""

    tlog: Path
    fc_returncode: int
    fc_summary: dict[str, Any]
    fc_output: list[str]
    steps: int
    wall_s: float
    #: rotorpy's state after each step: (t s, x, y, z ENU m).
    truth: list[tuple[float, float, float, float]] = field(default_factory=list)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _lockstep_vehicle_class() -> Any:
    import numpy as np
    from rotorpy.vehicles.ardupilot_multirotor import Ardupilot
    from rotorpy.vehicles.px4_multirotor import INT_MAX, INT_MIN, PX4Multirotor

    class LockstepPx4Multirotor(PX4Multirotor):  # type: ignore[misc]
        """rotorpy's PX4 vehicle, lockstep, FRD rates in HIL_STATE_QUATERNION, a motor fault (module docstring)."""

        def __init__(self, *args: Any, fault: MotorFault | None = None, answer_timeout_s: float = ANSWER_TIMEOUT_S, **kw: Any) -> None:
            super().__init__(*args, **kw)
            self.fault = fault
            self.answer_timeout_s = answer_timeout_s
            self._announced = False
            # sent as our simulator's component, so the FC relays and logs its announcements
            self.conn.mav.srcSystem, self.conn.mav.srcComponent = 1, SIM_COMPONENT_ID

        def step(self, state: dict[str, Any], control: dict[str, Any], t_step: float) -> dict[str, Any]:
            f = self.fault
            if f is not None and not self._announced and self.t >= f.at_s:
                self._announced = True  # as our simulator announces a fault: its start's metrics (recovery) key on it
                text = f"SIM: motor {f.rotor} at {f.efficiency * 100:.0f}%"
                self.conn.mav.statustext_send(mavlink.MAV_SEVERITY_WARNING, text.encode())
            return super().step(state, control, t_step)

        def _fetch_latest_px4_control(self, blocking: bool = True) -> dict[str, Any] | None:
            t_us = int(self.t * 1e6)
            deadline = time.monotonic() + self.answer_timeout_s
            while True:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise TimeoutError(f"no HIL_ACTUATOR_CONTROLS for t = {t_us} us within {self.answer_timeout_s:g} s")
                msg = self.conn.recv_match(type="HIL_ACTUATOR_CONTROLS", blocking=True, timeout=min(remaining, 0.5))
                if msg is not None and abs(int(msg.time_usec) - t_us) <= 10:
                    break
            speeds = [c * self.rotor_speed_max for c in msg.controls[: self.num_rotors]]
            f = self.fault
            if f is not None and self.t >= f.at_s:
                speeds[f.rotor - 1] *= math.sqrt(f.efficiency)
            return {"cmd_motor_speeds": speeds}

        def _send_hil_state_quaternion(self, state: dict[str, Any], statedot: dict[str, Any]) -> None:
            lat_deg, lon_deg, height_m = self.enu_to_geodetic(*state["x"])
            lat_e7, lon_e7, alt_mm = self.geodetic_to_mavlink(lat_deg, lon_deg, height_m)
            q = Ardupilot._quaternion_rotorpy_to_aerospace(state["q"])
            vx, vy, vz = self._enu_to_ned_cmps(state["v"])
            a_flu = self.imu.measurement(state, statedot, with_noise=False)["accel"]
            a_mg = np.clip(np.round(np.array([a_flu[0], -a_flu[1], -a_flu[2]]) / 9.80665 * 1000.0), INT_MIN, INT_MAX)
            w = state["w"]
            self.conn.mav.hil_state_quaternion_send(
                int(self.t * 1e6), q, float(w[0]), -float(w[1]), -float(w[2]), lat_e7, lon_e7, alt_mm, vx, vy, vz, 0, 0,
                int(a_mg[0]), int(a_mg[1]), int(a_mg[2]),
            )  # fmt: skip

    return LockstepPx4Multirotor


def fly(
    quad_params: Mapping[str, Any],
    *,
    plan: Path,
    duration_s: float,
    out_dir: Path,
    rate_hz: float = 250.0,
    fault: MotorFault | None = None,
    fc_args: Sequence[str] = (),
    seed: int = 0,
) -> RotorpyFlight:
    """Fly ``plan`` for ``duration_s`` simulated seconds: our FC (a process) on rotorpy's vehicle
    of ``quad_params`` through PX4's simulator API, lockstep at ``rate_hz``. The FC's vehicle is
    rotorpy's mapped by :func:`vehicle_from_rotorpy`; its motor order is the params' (:func:`rotorpy_frame`)."""
    import numpy as np

    out_dir.mkdir(parents=True, exist_ok=True)
    vehicle_file = out_dir / "rotorpy-vehicle.toml"
    vehicle_file.write_text(vehicle_from_rotorpy(quad_params).to_toml(), encoding="utf-8")
    port = _free_port()
    tlog = out_dir / "fc.tlog"
    fc_cmd = [sys.executable, "-m", "fc", "--sim", f"px4:tcp:127.0.0.1:{port}", "--px4-frame", rotorpy_frame(quad_params),
              "--px4-motor", "speed", "--rate-hz", f"{rate_hz:g}", "--vehicle", str(vehicle_file), "--plan", str(plan),
              "--duration", f"{duration_s:g}", "--gcs", "none", "--tlog", str(tlog), *fc_args]  # fmt: skip
    # The FC first (it retries until rotorpy listens); rotorpy's vehicle waits for its heartbeat.
    fc_out = out_dir / "fc.out"
    with fc_out.open("w", encoding="utf-8") as sink:  # a file, not a pipe: nobody reads it during the flight
        fc = subprocess.Popen(fc_cmd, cwd=out_dir, stdin=subprocess.DEVNULL, stdout=sink, stderr=subprocess.STDOUT, text=True)
    truth: list[tuple[float, float, float, float]] = []
    t0 = time.monotonic()
    steps = 0
    try:
        np.random.seed(seed)  # rotorpy's IMU noise (HIL_SENSOR, logged by the FC, not flown on)
        vehicle_class = _lockstep_vehicle_class()
        n = len(quad_params["rotor_pos"])
        initial = {"x": np.zeros(3), "v": np.zeros(3), "q": np.array([0.0, 0.0, 0.0, 1.0]), "w": np.zeros(3),
                   "wind": np.zeros(3), "rotor_speeds": np.zeros(n)}  # fmt: skip
        vehicle = vehicle_class(dict(quad_params), initial_state=initial, mavlink_url=f"tcpin:127.0.0.1:{port}", fault=fault,
                                integrator_kwargs={"method": "RK45"})  # fmt: skip
        state = initial
        dt = 1.0 / rate_hz
        total = int(round(duration_s * rate_hz))
        for k in range(total + 1):  # states at 0, dt, ..., duration: the FC answers each and stops after the last
            vehicle.t = k * dt  # no float drift in time_usec
            state = vehicle.step(state, {"cmd_motor_speeds": np.zeros(n)}, dt)
            steps += 1
            truth.append(((k + 1) * dt, float(state["x"][0]), float(state["x"][1]), float(state["x"][2])))
        vehicle.conn.close()
        fc.wait(timeout=30.0)
    finally:
        if fc.poll() is None:
            fc.kill()
            fc.wait()
    lines = fc_out.read_text(encoding="utf-8").splitlines()
    summary: dict[str, Any] = {}
    for line in lines:
        if line.startswith("FC_SUMMARY "):
            summary = json.loads(line.split(" ", 1)[1])
    return RotorpyFlight(tlog, fc.returncode, summary, lines, steps, time.monotonic() - t0, truth)
