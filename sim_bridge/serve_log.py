"""The flight log of a served flight: what ``smcpilot sim --serve`` gave another autopilot and got back.

A standard ``.tlog`` (pymavlink reads it; :mod:`smcpilot.tlog`), written with the messages our own
flight controller's log holds, so ``smcpilot log summary`` scores another autopilot's flight with
the metrics of ours (:mod:`ground.logs.summary`):

- first, at 0: ``STATUSTEXT`` (INFO) ``smcpilot sim --serve KIND`` (:data:`SERVED_PREFIX`: the log
  reader knows a served log by it);
- every state (the vehicle at rest before the first step, then after every physics step), from
  our simulator's component (200), stamped with it: ``ATTITUDE`` + ``LOCAL_POSITION_NED`` (the
  sensors' output, NED/FRD, noise and sensor faults included; a dropped-out sensor NaN, where the
  protocol sent its last value) with ``HIGHRES_IMU`` (the IMU's specific force and rates, body FRD)
  and ``ODOMETRY`` (the plant's true state, ``estimator_type`` MOCAP), as our simulator sends them
  with each state;
- every physics step, stamped with its start: ``HIL_ACTUATOR_CONTROLS`` from the autopilot's
  component (1): ``controls[0..3]`` our rotors 1..4 (right, front, left, rear) as flown, in
  [0, 1]; ``mode`` MAV_MODE_FLAG_SAFETY_ARMED while the rotors spin; ``flags`` bit 0 when the step
  was lockstep (every ArduPilot frame; a PX4 step answering its ``HIL_ACTUATOR_CONTROLS``);
- every fault start and stop: ``STATUSTEXT`` from component 200 at its time (WARNING for a start,
  INFO for a stop: ``SIM: motor 1 at 70%``), and a restart of the autopilot (a WARNING).

Time is served time: simulated seconds since the server started, going on across an autopilot's
restart (the fresh vehicle's states follow the old one's, one step later).
"""

from __future__ import annotations

from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sim_bridge.plants.paper_vehicle import PaperVehiclePlant
from sim_bridge.plants.rigid_body import RigidBodyPlant
from sim_bridge.sensors import specific_force_frd
from smcpilot.fastcodec import TickRecords, encode_hil_actuator_controls
from smcpilot.frames import quat_nwu_flu_to_ned_frd
from smcpilot.protocol import SIM_COMPONENT_ID
from smcpilot.tlog import TlogWriter
from smcpilot.wire import wire_of_paper

__all__ = ["SERVED_PREFIX", "AUTOPILOT_COMPONENT_ID", "ServedLog"]

#: the text of a served log's first STATUSTEXT, followed by the protocol served (``px4``, ``ardupilot-json``).
SERVED_PREFIX = "smcpilot sim --serve "
#: the component the motor commands are logged from (MAV_COMP_ID_AUTOPILOT1: the autopilot's).
AUTOPILOT_COMPONENT_ID = 1
_ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED
_ZEROS12 = [0.0] * 12
#: ODOMETRY's covariances: unknown (NaN first, as MAVLink says).


class ServedLog:
    """Writes a served flight's ``.tlog`` (see the module docstring). ``sysid`` is the vehicle's
    MAVLink system id in the log."""

    def __init__(self, path: Path, kind: str, sysid: int = 1) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self.tlog = TlogWriter(path)
        self.sysid = sysid
        self._records = TickRecords(sysid)
        self._sim_seq = 0
        self._ap_seq = 0
        #: the offset of the current plant's time in served time (µs), and the last state's stamp.
        self._offset_us = 0
        self._last_state_us: int | None = None
        self.states = 0
        self.commands = 0
        self._mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=SIM_COMPONENT_ID)
        self.event(0, mavlink.MAV_SEVERITY_INFO, SERVED_PREFIX + kind)

    def stamp_us(self, plant_t_s: float) -> int:
        """The served time (µs) of a time of the current plant."""
        return self._offset_us + int(round(plant_t_s * 1e6))

    def restarted(self, step_us: int) -> None:
        """The autopilot restarted: a fresh plant from 0; its time goes on one step after the last state."""
        if self._last_state_us is not None:
            self._offset_us = self._last_state_us + max(1, step_us)
            self._last_state_us = None

    def event(self, t_us: int, severity: int, text: str) -> None:
        mav = self._mav
        mav.seq = self._sim_seq
        self.tlog.write(t_us, mav.statustext_encode(severity, text[:50].encode("ascii", "replace")).pack(mav))
        self._sim_seq = mav.seq

    def state(self, plant: RigidBodyPlant | PaperVehiclePlant, gravity_mps2: float) -> None:
        """The plant's state now (once a time): the sensors' output, the IMU and the truth."""
        t_us = self.stamp_us(plant.t_s)
        if t_us == self._last_state_us:
            return
        self._last_state_us = t_us
        obs = plant.observe()
        tru = plant.truth()
        (phi, theta, psi), (p, q, r), (x, y, z), (vx, vy, vz) = obs.euler_rad, obs.body_rates_radps, obs.position_m, obs.velocity_mps
        roll, pitch, yaw, ps, qs, rs, xn, yn, zn, vxn, vyn, vzn = wire_of_paper(phi, theta, psi, p, q, r, x, y, z, vx, vy, vz)
        fx, fy, fz = specific_force_frd(obs.accel_mps2, tru.quaternion, gravity_mps2)
        (phi, theta, psi), (p, q, r), (x, y, z), (vx, vy, vz) = tru.euler_rad, tru.body_rates_radps, tru.position_m, tru.velocity_mps
        _, _, _, tp, tq, tr, tx, ty, tz, tvx, tvy, tvz = wire_of_paper(phi, theta, psi, p, q, r, x, y, z, vx, vy, vz)
        s, rec = self._sim_seq, self._records
        t_ms = (t_us // 1000) & 0xFFFFFFFF
        qw, qx, qy, qz = quat_nwu_flu_to_ned_frd(tru.quaternion)
        packets = (  # in the order our FC logs a state: the state pair, then the IMU and the truth
            rec.attitude(s, t_ms, roll, pitch, yaw, ps, qs, rs),
            rec.local_position_ned((s + 3) & 0xFF, t_ms, xn, yn, zn, vxn, vyn, vzn),
            rec.highres_imu((s + 1) & 0xFF, t_us, fx, fy, fz, ps, qs, rs),
            rec.odometry((s + 2) & 0xFF, t_us, tx, ty, tz, qw, qx, qy, qz, tvx, tvy, tvz, tp, tq, tr),
        )
        self._sim_seq = (s + 4) & 0xFF
        self.tlog.write_many(t_us, packets)
        self.states += 1

    def commands_flown(self, t_us: int, commands: tuple[float, float, float, float], armed: bool, lockstep: bool) -> None:
        """The motor commands of the step starting at ``t_us`` (served time)."""
        self.tlog.write(t_us, encode_hil_actuator_controls(
            self._ap_seq, self.sysid, AUTOPILOT_COMPONENT_ID, t_us, [*commands, *_ZEROS12], _ARMED if armed else 0, 1 if lockstep else 0,
        ))  # fmt: skip
        self._ap_seq = (self._ap_seq + 1) & 0xFF
        self.commands += 1

    def close(self) -> None:
        self.tlog.close()
