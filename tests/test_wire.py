"""The one wire <-> paper-frame conversion (smcpilot.wire): exact sign flips, Euler-angle rates from
the body rates (oracle: smcpilot.frames and a rotation built with scipy), NaN kept."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from smcpilot.frames import euler_rates_to_body_rates
from smcpilot.wire import paper_of_wire, wire_of_paper

angle = st.floats(-3.0, 3.0)
tilt = st.floats(-1.2, 1.2)
val = st.floats(-100.0, 100.0)


@given(angle, tilt, angle, val, val, val, val, val, val, val, val, val)
def test_the_round_trip_is_exact_and_rates_are_euler_rates(phi, theta, psi, p, q, r, x, y, z, vx, vy, vz) -> None:
    w = wire_of_paper(phi, theta, psi, p, q, r, x, y, z, vx, vy, vz)
    # NED/FRD: the sign flips of the frames, bit for bit
    assert w == (phi, -theta, -psi, p, -q, -r, x, -y, -z, vx, -vy, -vz)
    back = paper_of_wire(*w)
    assert back[:6] == (x, y, z, vx, vy, vz) and back[6:9] == (phi, theta, psi) and back[12:] == (p, q, r)
    # the Euler-angle rates give back the body rates
    pb = euler_rates_to_body_rates(phi, theta, back[9], back[10], back[11])
    assert np.allclose(pb, (p, q, r), rtol=1e-9, atol=1e-9 * (1.0 + abs(p) + abs(q) + abs(r)) / math.cos(theta) ** 2)


def test_the_wire_attitude_is_the_ned_frd_rotation() -> None:
    """ZYX angles on the wire describe the same rotation as the paper's FLU-in-NWU ones, seen from NED/FRD."""
    phi, theta, psi = 0.3, -0.4, 2.0
    roll, pitch, yaw = wire_of_paper(phi, theta, psi, 0, 0, 0, 0, 0, 0, 0, 0, 0)[:3]
    flip = np.diag([1.0, -1.0, -1.0])  # NWU <-> NED and FLU <-> FRD
    r_paper = Rotation.from_euler("ZYX", [psi, theta, phi]).as_matrix()
    r_wire = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
    assert np.allclose(flip @ r_paper @ flip, r_wire)


def test_nan_stays_nan() -> None:
    nan = math.nan
    out = paper_of_wire(nan, 0.1, 0.2, 0.0, 0.0, 0.0, nan, 1.0, 2.0, 0.0, 0.0, nan)
    assert math.isnan(out[0]) and math.isnan(out[6]) and math.isnan(out[5]) and out[1] == -1.0
