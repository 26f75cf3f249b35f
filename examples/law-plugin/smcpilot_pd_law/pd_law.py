"""A PD law on feedback linearisation of the paper's model: the tutorial's law (docs/your-own-law.md).

Per channel k: the acceleration wanted is the reference's plus PD feedback on the errors, and the
model is inverted for the input that gives it, u_k = (a_k - f_k(X)) / g_k(X). Altitude adds an
integrator (anti-windup: it holds while the mixer limits the thrust).
"""

from dataclasses import dataclass

from fc.control.law import Law, param
from smcpilot.model import drift, tilt_cos


@dataclass(frozen=True)
class PdParams:
    kp_att: float = param(64.0, lo=0.0, hi=1000.0, unit="1/s^2", doc="roll/pitch: angle error -> angular acceleration")
    kd_att: float = param(16.0, lo=0.0, hi=100.0, unit="1/s", doc="roll/pitch: rate error -> angular acceleration")
    kp_yaw: float = param(16.0, lo=0.0, hi=1000.0, unit="1/s^2", doc="yaw: angle error -> angular acceleration")
    kd_yaw: float = param(8.0, lo=0.0, hi=100.0, unit="1/s", doc="yaw: rate error -> angular acceleration")
    kp_z: float = param(4.0, lo=0.0, hi=100.0, unit="1/s^2", doc="altitude error -> vertical acceleration")
    kd_z: float = param(4.0, lo=0.0, hi=100.0, unit="1/s", doc="climb-rate error -> vertical acceleration")
    ki_z: float = param(1.0, lo=0.0, hi=100.0, unit="1/s^3", doc="integral of the altitude error")


def pd_consts(ctx, p):
    """Flatten once: the model's constants (mass, b1..b3, drift coefficients) and the gains."""
    return (tuple(ctx.model.consts()), p.kp_att, p.kd_att, p.kp_yaw, p.kd_yaw, p.kp_z, p.kd_z, p.ki_z)


def pd_init(meas, k):
    return (0.0,)  # the altitude integrator


def pd_step(meas, ref, state, dt_s, k, d_hat, u_prev):
    m, kpa, kda, kpy, kdy, kpz, kdz, kiz = k
    phi, phi_d, th, th_d, psi, psi_d, z, z_d = meas
    f0, f1, f2, f3 = drift(m, phi_d, th_d, psi_d, z_d, 0.0)
    a0 = ref[2] + kda * (ref[1] - phi_d) + kpa * (ref[0] - phi)
    a1 = ref[6] + kda * (ref[5] - th_d) + kpa * (ref[4] - th)
    a2 = ref[10] + kdy * (ref[9] - psi_d) + kpy * (ref[8] - psi)
    ez = ref[12] - z
    iz = state[0] + dt_s * ez
    a3 = ref[14] + kdz * (ref[13] - z_d) + kpz * ez + kiz * iz
    gz = tilt_cos(phi, th, 0.05) / m[0]  # m[0] mass_kg; m[13..15] b1, b2, b3
    u = ((a0 - f0) / m[13], (a1 - f1) / m[14], (a2 - f2) / m[15], (a3 - f3) / gz)
    zero = (0.0, 0.0, 0.0, 0.0)
    return u, (iz,), (zero, zero, zero, zero)


def pd_anti_windup(prev, new, u_realised, limited, k):
    return (prev[0],) if limited[3] else new


PD_LAW = Law(
    name="pd_feedback", stage="attitude", prefix="PDL",
    description="PD on feedback linearisation of the paper's model (the tutorial's law)",
    params_class=PdParams, consts=pd_consts,
    initial_state=pd_init, step=pd_step, anti_windup=pd_anti_windup,
    state_names=("int_e_z",), reference="docs/your-own-law.md",
)
