"""Contracts every part of smcpilot shares: mode and command numbers, controller names, telemetry
names, the per-tick ``SMC`` log record and its flags.

The flight controller (``fc``) writes these, the ground tools (``ground``) and the lab (``lab``)
read them; defining them here lets ``ground`` talk to the FC through MAVLink alone, never by
importing ``fc``.

- **Modes** are ArduCopter's custom-mode numbers, taken from the MAVLink ``COPTER_MODE`` enum of
  pymavlink's generated dialect, never retyped. :data:`FLOWN_MODES` are the ones this FC flies;
  every other ArduCopter mode is known by name and refused.
- **Telemetry**: the adaptive gains and the sliding variables are ``NAMED_VALUE_FLOAT``
  :data:`CHI_NAMES` and :data:`SIG_NAMES`, channel order phi, theta, psi, z.
- **The SMC record**: every control tick the FC logs a ``DEBUG_FLOAT_ARRAY`` named ``SMC``
  (array id :data:`SMC_ARRAY_ID`) whose entries :data:`SMC_FIELDS` names, in the paper's frame
  (x north, y west, z up; FLU body). The ``flags`` entry holds the ``FLAG_*`` bits.
"""

from __future__ import annotations

from enum import IntEnum

from pymavlink.dialects.v20 import ardupilotmega as _mavlink

# -- modes -----------------------------------------------------------------------------------------
#: ArduCopter custom-mode number -> name, all of them: the MAVLink ``COPTER_MODE`` enum of
#: pymavlink's generated ardupilotmega dialect (importing ``mavutil`` for its table would cost every
#: process ~0.13 s of start-up).
COPTER_MODE_NAMES: dict[int, str] = {
    number: entry.name.removeprefix("COPTER_MODE_")
    for number, entry in _mavlink.enums["COPTER_MODE"].items()
    if entry.name != "COPTER_MODE_ENUM_END"
}
#: ArduCopter custom-mode name -> number.
COPTER_MODES: dict[str, int] = {name: number for number, name in sorted(COPTER_MODE_NAMES.items())}


class Mode(IntEnum):
    """The modes this FC flies, numbered as ArduCopter's (docs/gcs-protocol.md)."""

    ALT_HOLD = COPTER_MODES["ALT_HOLD"]
    AUTO = COPTER_MODES["AUTO"]
    GUIDED = COPTER_MODES["GUIDED"]
    LOITER = COPTER_MODES["LOITER"]
    RTL = COPTER_MODES["RTL"]
    LAND = COPTER_MODES["LAND"]


#: Modes the FC flies; every other ArduCopter mode is refused (they need RC sticks or hardware).
FLOWN_MODES: frozenset[int] = frozenset(int(m) for m in Mode)
#: ArduCopter's other modes: known by name, refused by this FC.
REFUSED_MODES: dict[int, str] = {n: name for n, name in COPTER_MODE_NAMES.items() if n not in FLOWN_MODES}
#: Modes one may arm in.
ARMABLE_MODES: frozenset[Mode] = frozenset({Mode.ALT_HOLD, Mode.AUTO, Mode.GUIDED, Mode.LOITER})


def mode_name(number: int) -> str:
    """ArduCopter name of a custom-mode number (``MODE_<n>`` if ArduCopter has none)."""
    return COPTER_MODE_NAMES.get(number, f"MODE_{number}")


def flown_mode_from_name(name: str) -> Mode:
    """A mode this FC flies, by name (case-insensitive); ValueError naming the valid ones."""
    key = name.strip().upper()
    if key in Mode.__members__:
        return Mode[key]
    valid = ", ".join(m.name for m in Mode)
    if key in COPTER_MODES:
        raise ValueError(f"mode {key} is not supported by this flight controller (it needs RC input); use one of {valid}")
    raise ValueError(f"unknown mode {name!r}; use one of {valid}")


# -- commands --------------------------------------------------------------------------------------
#: where the FC sends ground telemetry by default (QGroundControl and MAVProxy listen there).
DEFAULT_GCS_URL = "udp:127.0.0.1:14550"
#: the FC's own ground port with the default ground link: a second station (``smcpilot gcs``
#: while ``smcpilot gcs watch`` holds 14550) writes to it and is answered (``udpout:127.0.0.1:14551``).
FC_GROUND_PORT = 14551
#: ``param2`` of MAV_CMD_COMPONENT_ARM_DISARM that forces arming or disarming (ArduPilot's value).
FORCE_ARM_MAGIC = 21196.0

#: Component id of the flight controller (MAV_COMP_ID_AUTOPILOT1).
FC_COMPONENT_ID = 1
#: Component id the simulator bridge speaks with.
SIM_COMPONENT_ID = 200
#: ``HIGHRES_IMU.fields_updated`` of the simulator's IMU: the accelerometer (bits 0-2) and the
#: gyro (bits 3-5); a sensor's dropout is NaN in its fields, not a cleared bit.
IMU_ACCEL_BITS = 0x07
IMU_GYRO_BITS = 0x38
IMU_FIELDS_UPDATED = IMU_ACCEL_BITS | IMU_GYRO_BITS
#: ``ODOMETRY`` of the plant's true state (logged for scoring; never flown on): frames
#: (MAV_FRAME_LOCAL_NED for the pose and the velocity), estimator type (MAV_ESTIMATOR_TYPE_MOCAP:
#: what a motion-capture system would give, the truth) and quality (100).
TRUTH_FRAME = 1
TRUTH_ESTIMATOR_TYPE = 6
TRUTH_QUALITY = 100
#: ODOMETRY's covariances in the truth: unknown (NaN in the first element, as MAVLink says).
COV_UNKNOWN = (float("nan"),) + (0.0,) * 20

# -- controllers -----------------------------------------------------------------------------------
#: The built-in control laws the flight controller flies (FC_CONTROLLER values 0..5; plug-ins follow,
#: see fc.control.registry and smcpilot.lawref).
FC_CONTROLLERS: tuple[str, ...] = ("adaptive_pid_smc", "pid_smc", "cascade_pid", "sign_smc", "se3_geometric", "indi")
#: Every control law, in the order reports list them (the paper scenario adds the sign-SMC).
CONTROLLER_NAMES: tuple[str, ...] = ("pid_smc", "adaptive_pid_smc", "sign_smc", "cascade_pid")

# -- telemetry -------------------------------------------------------------------------------------
CHANNEL_TAGS: tuple[str, ...] = ("PHI", "THETA", "PSI", "Z")
#: NAMED_VALUE_FLOAT names of the adaptive gains chi_hat, channel order phi, theta, psi, z.
CHI_NAMES: tuple[str, ...] = tuple(f"CHI_{c}" for c in CHANNEL_TAGS)
#: NAMED_VALUE_FLOAT names of the sliding variables sigma.
SIG_NAMES: tuple[str, ...] = tuple(f"SIG_{c}" for c in CHANNEL_TAGS)
#: NAMED_VALUE_INT name of the missed-deadline counter.
OVERRUN_NAME = "OVERRUN"

# -- the per-tick SMC log record -------------------------------------------------------------------
#: ``DEBUG_FLOAT_ARRAY.name`` of the per-tick record.
SMC_ARRAY_NAME = b"SMC"
#: ``DEBUG_FLOAT_ARRAY.array_id`` of the per-tick record.
SMC_ARRAY_ID = 1
#: Entries of the per-tick record (paper frame, channel order phi, theta, psi, z).
SMC_FIELDS: tuple[str, ...] = (
    ("chi_phi", "chi_theta", "chi_psi", "chi_z")
    + ("sigma_phi", "sigma_theta", "sigma_psi", "sigma_z")
    + ("s_phi", "s_theta", "s_psi", "s_z")
    + ("u_phi", "u_theta", "u_psi", "u_z")
    + ("ref_phi", "ref_theta", "ref_psi", "ref_z")
    + ("motor1", "motor2", "motor3", "motor4")
    + ("target_x", "target_y", "target_z", "target_yaw")
    + ("limited_mask", "flags", "mode")
)
#: bits of the record's ``flags`` entry
FLAG_ARMED = 1
FLAG_LANDING = 2
FLAG_FAILSAFE = 4
FLAG_POSITION_HOLD = 8

#: ``HIL_ACTUATOR_CONTROLS.flags`` bit: the FC runs in lockstep.
ACTUATOR_FLAG_LOCKSTEP = 1
