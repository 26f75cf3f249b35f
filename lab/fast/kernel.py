"""The compiled flight kernel: tick after tick of a whole in-process flight, until something discrete is due.

One call of :func:`fly_span` flies what :func:`lab.runner.simulate` flies per tick — the plant's
observation with sensor noise, the NED/FRD float32 wire round trip, the FC's estimate, the mode's
per-tick check, the pipeline with the law and the mixer, the float32 motor commands, the physics
sub-steps with gusts — for as long as every tick is *plain*: nothing happens that the Python side
(:mod:`lab.fast.flight`) must handle. It returns at the first tick that is not, **before** that
tick changes anything (so Python flies it with the ordinary objects), handing over the observation
already drawn for it. A tick is not plain when:

- a plan step is due, or a fault starts or stops during it (the driver limits the span);
- the estimate is not "everything measured" (a dropout: the driver does not start a span then);
- the commander's disarm delay runs out, or the mode's watched condition holds (a take-off height
  reached, a waypoint within its radius, home reached, a hold time over: :mod:`fc.modes` ``watch``);
- the pipeline touches down while landing, or the law's output is not finite;
- the float32 wire conversion would overflow (CPython raises there).

The physics diverging returns its own code and time (the driver raises
:class:`smcpilot.errors.DivergenceError` as the plant does). Everything here is in the pure style
(plain floats, NamedTuples, numpy arrays for what the kernel owns and mutates): CPython can run it,
numba compiles it (:func:`smcpilot.jit.compile_pure`).
"""

from __future__ import annotations

import math

import numpy as np

from fc.commander import ground_armed_count
from fc.estimate import EST_DEAD_RECKONING, estimate_step
from fc.modes.base import watch_holds as _watch_holds
from fc.pipeline import VehicleState, pipeline_step_sensed
from lab.fast.mt import mt_gauss, mt_gauss_fill
from sim_bridge.plants.rigid_body import heading, heading_turns, rigid_body_substep_lag, rigid_body_targets, rotor_lag
from sim_bridge.sensors import specific_force_frd
from smcpilot.frames import euler_from_quat, euler_from_quat_heading, wrap_pi
from smcpilot.protocol import FLAG_ARMED, FLAG_LANDING, FLAG_POSITION_HOLD
from smcpilot.wire import accel_of_specific_force, paper_of_wire, wire_of_paper

#: return codes of :func:`fly_span` (``io[1]``).
SPAN_DONE = 0  # flew the ticks asked for
SPAN_EVENT = 1  # the next tick is not plain; its observation is in ``obs``
SPAN_DIVERGED = 2  # the physics became non-finite at ``io_f[0]`` seconds
SPAN_OVERFLOW = 3  # the wire's float32 would overflow on the next tick; its observation is in ``obs``


_F32_MAX = 3.4028234663852886e38
_exp = math.exp
_sqrt = math.sqrt
_isfinite = math.isfinite

#: columns of a recorded row (what :class:`lab.metrics.MetricsRecorder` keeps).
ROW_COLUMNS = 26
#: sensor-fault modes of the kernel's program (``sp``); delay is flown in Python.
SF_STUCK = 1
SF_BIAS = 2
SF_NOISE = 3
SF_DROPOUT = 4
#: columns of a fault gust's row: state (N, E, x, y, z), force std, torque std, tau, last step, a, b.
FG_COLUMNS = 11
#: columns of a log row (what :class:`lab.run._TlogRecorder` writes for a tick): time, the 12 wire
#: values, the motor commands, armed, the 31 leading values of the ``SMC`` record, then the IMU's
#: specific force (body FRD, m/s^2, float64 as computed: ``HIGHRES_IMU``) and the plant's true state
#: at the tick (its 13 leading states: position, velocity, attitude quaternion, body rates, in the
#: paper's frames: ``ODOMETRY``).
LOG_COLUMNS = 65
#: the first column of the specific force and of the true state in a log row.
LOG_IMU = 49
LOG_TRUTH = 52


def _f32(x: float) -> float:
    return np.float64(np.float32(x))


def _f32_overflows(x: float) -> bool:
    """Packing ``x`` as float32 raises in CPython (finite, but rounds beyond the float32 range)."""
    return _isfinite(x) and (x > _F32_MAX or x < -_F32_MAX) and not _isfinite(_f32(x))


def _noise_draws(std: float) -> int:
    """How many draws a 3-vector's white noise of ``std`` takes (none for 0)."""
    return 3 if std > 0.0 else 0


def _noisy3(a: float, b: float, c: float, std: float, z0: float, z1: float, z2: float) -> tuple[float, float, float]:
    """Three values with white noise of ``std`` (``random.gauss(0.0, std)`` of the unit deviates
    ``z``), or unchanged for 0 (then the draws are not used)."""
    if std <= 0.0:
        return a, b, c
    return a + (0.0 + z0 * std), b + (0.0 + z1 * std), c + (0.0 + z2 * std)


def _sensed_none(ok: bool, f0: float, f1: float, f2: float, phi: float, theta: float, psi: float, g: float) -> tuple[()]:
    """What a law that takes nothing sensed beyond the state gets: nothing. The kernel calls
    :func:`fc.pipeline.pipeline_step_sensed` (for a whole-stack law
    :func:`fc.pipeline.pipeline_step_full_sensed` takes its place) with it; for a law that measures
    acceleration :func:`_sensed_imu` takes its place."""
    return ()


def _sensed_imu(ok: bool, f0: float, f1: float, f2: float, phi: float, theta: float, psi: float, g: float) -> tuple[float, float, float]:
    """What a law that measures acceleration gets: the IMU's (paper frame) of the specific force
    ``f`` as the wire carries it, rotated with the estimate's attitude; NaN unless ``ok``."""
    if ok:
        return accel_of_specific_force(f0, f1, f2, phi, theta, psi, g)
    return (math.nan, math.nan, math.nan)


def fly_span(
    pp, ps, cmd, armed, position_hold, dt_ctrl, ep, es, t0_us, fc_f, watch, plan_next_s,
    plant_s, plant_f, rbp, eff, paper, env_f, wind, add_forces, fault_force, fault_torque,
    gust, gust_std, gusts_on, noise_std, noise_on, gmt, ggs, nmt, ngs,
    t_us, step_us, substeps, dt_phys, n_ticks, rec, rec_every, rec_truth, rec_k0, sigma_ok, io, io_f, obs,
    log_on, lg, diag_mask, mode_num,
    fg, n_fg, fgmt, fggs, sp, sn, fnmt, fngs, est_prev, zb, imu_on, g_plant,
):  # fmt: skip
    """Fly up to ``n_ticks`` plain ticks from simulated time ``t_us`` (µs); returns
    ``(pipeline state, estimator state, last outputs, last estimate)``; ``io`` gets
    [ticks flown, code, rows recorded, time µs after them], ``io_f`` [divergence time s,
    ground-armed s]. On divergence the FC's part of the diverging tick is done (it is not counted
    in ``io[0]``) and ``io[3]`` is that tick's time.

    Arguments, by group (the driver, :mod:`lab.fast.flight`, builds them from the live objects):
    the pipeline's params/state/inputs, armed, position hold, the control
    period; the estimator's params/state; the time of the first tick (µs); ``fc_f`` = [disarm
    delay s, ground-armed s]; the mode's watch (kind, a, b, c, r); the next plan step's time (s
    since the first tick; inf: none); the plant's 17 states (array, updated), ``plant_f`` = [heading
    at the last step, heading turns, accel x3, the plant's time s], its params, the rotor efficiencies and paper
    disturbance in force; ``env_f`` = [gust step of the last draw, a, b, gust time constant]; the
    wind, whether fault forces are added and the fault force/torque; the 6 gust states (array)
    and stds; the noise stds (attitude, rates, position, velocity, accel); the MT19937 states of
    the gust and noise streams; time step (µs), physics sub-steps a tick and their length; the
    record array (rows of :data:`ROW_COLUMNS`), every how many ticks, of the true state or the
    received one, the tick number of the first tick, whether the law has a sigma; the output
    arrays; whether to log every tick into ``lg`` (rows of :data:`LOG_COLUMNS`: time µs, the 12
    wire values, the motor commands, armed, the 31 leading values of the ``SMC`` record of
    :func:`fc.telemetry.smc_data`, the IMU's specific force and the plant's true state), which of the law's diagnostics exist (s, sigma, chi_hat,
    u_dot) and the mode's number; the faults' gusts (``fg``: one row each, :data:`FG_COLUMNS`;
    ``n_fg`` of them) and their random stream; the sensor faults as a program per sensor (``sp``
    [sensor, op] = (mode, x, y, z) in the paper's frames, ``sn`` ops per sensor, sensors in
    :data:`smcpilot.faults.SENSORS` order) and their noise stream; the estimate's status before
    the span (a tick whose status differs is not plain); a scratch array of at least
    ``15 + 6 + 5 n_fg`` floats for the Gaussian draws; whether the law measures acceleration (it
    then gets the IMU: the observed acceleration as the accelerometer's specific force with the
    true attitude, float32 as ``HIGHRES_IMU`` carries it, back to the paper frame with the state's
    attitude: :func:`lab.runner.imu_accel` and :meth:`fc.flight.FlightControl.step`) and the
    plant's gravity.

    Random draws are taken a batch at a time (:func:`lab.fast.mt.mt_gauss_fill`: the tick's sensor
    noise, a physics step's gusts) and arrays are indexed, never sliced into row views: compiled,
    each array handed to a call or viewed costs atomic reference counting.
    """
    tx, ty, tz, psi_target, _armed, landing, _hold, _vxy = cmd
    law_k = _kernel_law()
    disarm_delay = fc_f[0]
    ground_s = fc_f[1]
    wkind, wa, wb, wc, wr = watch
    n_rec = io[2]
    flags = (FLAG_ARMED if armed else 0) | (FLAG_LANDING if landing else 0) | (FLAG_POSITION_HOLD if position_hold else 0)
    yaw_target = wrap_pi(psi_target)
    nan = math.nan
    out = (
        (0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), (False, False, False, False),
        (nan, nan, nan, nan), (nan, nan, nan, nan), (nan, nan, nan, nan), (0.0, 0.0, 0.0, 0.0),
        (nan, nan, nan, nan), (nan, nan, nan, nan), False, (0.0, 0.0, 0.0, 0.0),
    )  # fmt: skip
    est = VehicleState(nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan)
    psi0 = plant_f[0]
    turns = plant_f[1]
    acc_x = plant_f[2]
    acc_y = plant_f[3]
    acc_z = plant_f[4]
    last_h = env_f[0]
    ga = env_f[1]
    gb = env_f[2]
    g_tau = env_f[3]
    s_att, s_rate, s_pos, s_vel, s_acc = noise_std
    # draws a tick (sim_bridge.sensors.SensorNoise.apply: attitude, position, velocity, rates, accel)
    n_noise = _noise_draws(s_att) + _noise_draws(s_pos) + _noise_draws(s_vel) + _noise_draws(s_rate) + _noise_draws(s_acc)
    # draws a physics step: the environment's gusts, then the faults' (force N, E; torque x, y, z)
    n_gust = 0
    for j in range(6):
        if gust_std[j] > 0.0:
            n_gust += 1
    n_fgz = 0
    for gi in range(n_fg):
        n_fgz += (2 if fg[gi, 5] > 0.0 else 0) + (3 if fg[gi, 6] > 0.0 else 0)
    # the rotors' lag over half a physics step (the same for every step)
    e_half = rotor_lag(dt_phys, rbp)
    # the heading of the plant's state (its quaternion's, not normalised): each physics step
    # computes it for the next (the euler angles and the paper's disturbances read it)
    psi_s = heading(plant_s)
    k = 0
    code = 0
    n_missing = 0
    n_dr = 0
    last_missing = io[6]
    while k < n_ticks:
        # -- the observation (the plant's truth, sensor noise) and the wire ---------------------
        x, y, z, vx, vy, vz, qw, qx, qy, qz, p_, q_, r_, w1, w2, w3, w4 = (
            plant_s[0], plant_s[1], plant_s[2], plant_s[3], plant_s[4], plant_s[5], plant_s[6], plant_s[7],
            plant_s[8], plant_s[9], plant_s[10], plant_s[11], plant_s[12], plant_s[13], plant_s[14], plant_s[15],
            plant_s[16],
        )  # fmt: skip
        if qw * qw + qx * qx + qy * qy + qz * qz == 1.0:
            phi_t, theta_t, psi_t = euler_from_quat_heading((qw, qx, qy, qz), psi_s)
        else:
            phi_t, theta_t, psi_t = euler_from_quat((qw, qx, qy, qz))
        phi_t = wrap_pi(phi_t)
        psi_t = wrap_pi(psi_t)
        o_phi, o_theta, o_psi = phi_t, theta_t, psi_t
        ox, oy, oz, ovx, ovy, ovz = x, y, z, vx, vy, vz
        op, oq, o_r = p_, q_, r_
        oax, oay, oaz = acc_x, acc_y, acc_z
        if noise_on and n_noise > 0:
            mt_gauss_fill(nmt, ngs, zb, n_noise)
            j = 0
            if s_att > 0.0:
                o_phi = wrap_pi(o_phi + (0.0 + zb[0] * s_att))
                o_theta = o_theta + (0.0 + zb[1] * s_att)
                o_psi = wrap_pi(o_psi + (0.0 + zb[2] * s_att))
                j = 3
            # the order of sim_bridge.sensors.SensorNoise.apply: position, velocity, rates, accel
            ox, oy, oz = _noisy3(ox, oy, oz, s_pos, zb[j], zb[j + 1], zb[j + 2])
            j += _noise_draws(s_pos)
            ovx, ovy, ovz = _noisy3(ovx, ovy, ovz, s_vel, zb[j], zb[j + 1], zb[j + 2])
            j += _noise_draws(s_vel)
            op, oq, o_r = _noisy3(op, oq, o_r, s_rate, zb[j], zb[j + 1], zb[j + 2])
            j += _noise_draws(s_rate)
            oax, oay, oaz = _noisy3(oax, oay, oaz, s_acc, zb[j], zb[j + 1], zb[j + 2])
        # the sensor faults, sensor by sensor in SENSORS order, each sensor's in their order
        att_lost = False
        for si in range(5):
            nops = sn[si]
            if nops == 0:
                continue
            if si == 0:
                v0, v1, v2 = op, oq, o_r
            elif si == 1:
                v0, v1, v2 = oax, oay, oaz
            elif si == 2:
                v0, v1, v2 = o_phi, o_theta, o_psi
            elif si == 3:
                v0, v1, v2 = ox, oy, oz
            else:
                v0, v1, v2 = ovx, ovy, ovz
            dropped = False
            for oi in range(nops):
                mode = sp[si, oi, 0]
                p1 = sp[si, oi, 1]
                p2 = sp[si, oi, 2]
                p3 = sp[si, oi, 3]
                if mode == SF_STUCK:
                    v0, v1, v2 = p1, p2, p3
                elif mode == SF_BIAS:
                    v0, v1, v2 = v0 + p1, v1 + p2, v2 + p3
                elif mode == SF_NOISE:
                    if p1 > 0.0:
                        v0 = v0 + mt_gauss(fnmt, fngs, 0.0, p1)
                    if p2 > 0.0:
                        v1 = v1 + mt_gauss(fnmt, fngs, 0.0, p2)
                    if p3 > 0.0:
                        v2 = v2 + mt_gauss(fnmt, fngs, 0.0, p3)
                else:  # dropout
                    v0 = v1 = v2 = nan
                    dropped = True
            if si == 0:
                op, oq, o_r = v0, v1, v2
            elif si == 1:
                oax, oay, oaz = v0, v1, v2
            elif si == 2:
                if dropped:
                    att_lost = True
                else:
                    v0 = wrap_pi(v0)
                    v2 = wrap_pi(v2)
                o_phi, o_theta, o_psi = v0, v1, v2
            elif si == 3:
                ox, oy, oz = v0, v1, v2
            else:
                ovx, ovy, ovz = v0, v1, v2
        # hand-over values (the driver rebuilds the observation when it flies this tick itself)
        obs[0] = plant_f[5]
        obs[1] = ox
        obs[2] = oy
        obs[3] = oz
        obs[4] = ovx
        obs[5] = ovy
        obs[6] = ovz
        obs[7] = o_phi
        obs[8] = o_theta
        obs[9] = o_psi
        obs[10] = op
        obs[11] = oq
        obs[12] = o_r
        obs[13] = oax
        obs[14] = oay
        obs[15] = oaz
        obs[16] = 1.0 if att_lost else 0.0
        # the wire (smcpilot.wire): NED/FRD float32, then back to the paper frame
        w = wire_of_paper(o_phi, o_theta, o_psi, op, oq, o_r, ox, oy, oz, ovx, ovy, ovz)
        if (_f32_overflows(w[0]) or _f32_overflows(w[1]) or _f32_overflows(w[2]) or _f32_overflows(w[3])
                or _f32_overflows(w[4]) or _f32_overflows(w[5]) or _f32_overflows(w[6]) or _f32_overflows(w[7])
                or _f32_overflows(w[8]) or _f32_overflows(w[9]) or _f32_overflows(w[10]) or _f32_overflows(w[11])):  # fmt: skip
            code = 3
            break
        f0 = nan
        f1 = nan
        f2 = nan
        fa = (nan, nan, nan)
        if imu_on or log_on:
            fa = specific_force_frd((oax, oay, oaz), (qw, qx, qy, qz), g_plant)
        if imu_on:
            if _f32_overflows(fa[0]) or _f32_overflows(fa[1]) or _f32_overflows(fa[2]):
                code = 3
                break
            f0 = _f32(fa[0])
            f1 = _f32(fa[1])
            f2 = _f32(fa[2])
        w32 = (_f32(w[0]), _f32(w[1]), _f32(w[2]), _f32(w[3]), _f32(w[4]), _f32(w[5]), _f32(w[6]), _f32(w[7]),
               _f32(w[8]), _f32(w[9]), _f32(w[10]), _f32(w[11]))  # fmt: skip
        pw = paper_of_wire(w32[0], w32[1], w32[2], w32[3], w32[4], w32[5], w32[6], w32[7], w32[8], w32[9], w32[10], w32[11])
        st = VehicleState(pw[0], pw[1], pw[2], pw[3], pw[4], pw[5], pw[6], pw[7], pw[8], pw[9], pw[10], pw[11])
        # -- the FC's tick: the estimate, the plan, the commander, the pipeline ------------------
        es_new, est_new, status, missing = estimate_step(es, st, dt_ctrl, ep)
        if status != est_prev or status > EST_DEAD_RECKONING:
            code = 1
            break
        t_s = (t_us - t0_us) * 1e-6
        if plan_next_s <= t_s + 1e-9:
            code = 1
            break
        ex = est_new[0]
        ey = est_new[1]
        ez = est_new[2]
        new_ground = ground_s
        if armed:
            new_ground = ground_armed_count(ground_s, disarm_delay, ez, tz, landing, dt_ctrl)
            if new_ground >= disarm_delay > 0.0:
                code = 1
                break
            if _watch_holds(wkind, wa, wb, wc, wr, ex, ey, ez, t_s):
                code = 1
                break
            sensed = _sensed(imu_on and _isfinite(f0) and _isfinite(f1) and _isfinite(f2), f0, f1, f2, est_new[6], est_new[7],
                             est_new[8], pp.gravity_mps2)  # fmt: skip
            ps_new, out_new = pipeline_step_sensed(ps, est_new, cmd, pp, dt_ctrl, law_k, sensed)
            mo = out_new[0]
            ul = out_new[6]
            if out_new[9] or not (_isfinite(mo[0] + mo[1] + mo[2] + mo[3]) and _isfinite(ul[0] + ul[1] + ul[2] + ul[3])):
                code = 1
                break
            ps = ps_new
            out = out_new
        ground_s = new_ground
        es = es_new
        est = est_new
        if missing != 0:
            n_missing += 1
        if status == EST_DEAD_RECKONING:
            n_dr += 1
        last_missing = missing
        m0 = _f32(out[0][0])
        m1 = _f32(out[0][1])
        m2 = _f32(out[0][2])
        m3 = _f32(out[0][3])
        # -- the record (lab.metrics.MetricsRecorder's row) ------------------------------------
        if rec_every > 0 and (rec_k0 + k) % rec_every == 0:
            rec[n_rec, 0] = t_us * 1e-6
            if rec_truth:  # lab.runner.wire_state of the truth: its own wire round trip
                tw = wire_of_paper(phi_t, theta_t, psi_t, p_, q_, r_, x, y, z, vx, vy, vz)
                tp = paper_of_wire(_f32(tw[0]), _f32(tw[1]), _f32(tw[2]), _f32(tw[3]), _f32(tw[4]), _f32(tw[5]),
                                   _f32(tw[6]), _f32(tw[7]), _f32(tw[8]), _f32(tw[9]), _f32(tw[10]), _f32(tw[11]))  # fmt: skip
                for j in range(9):
                    rec[n_rec, 1 + j] = tp[j]
            else:
                for j in range(9):
                    rec[n_rec, 1 + j] = st[j]
            rec[n_rec, 10] = tx
            rec[n_rec, 11] = ty
            rec[n_rec, 12] = tz
            rec[n_rec, 13] = yaw_target
            rf = out[8]
            rec[n_rec, 14] = rf[0]
            rec[n_rec, 15] = rf[1]
            rec[n_rec, 16] = rf[2]
            rec[n_rec, 17] = m0
            rec[n_rec, 18] = m1
            rec[n_rec, 19] = m2
            rec[n_rec, 20] = m3
            rec[n_rec, 21] = flags
            sg = out[4]
            for j in range(4):
                rec[n_rec, 22 + j] = sg[j] if (sigma_ok and armed) else nan
            n_rec += 1
        # -- the log (what lab.run's tlog recorder writes for the tick) ----------------------------
        if log_on:
            lg[k, 0] = t_us
            for j in range(12):
                lg[k, 1 + j] = w32[j]
            mo = out[0]
            chi = out[5]
            sg = out[4]
            sv = out[3]
            uu = out[1]
            rf = out[8]
            lg[k, 17] = 1.0 if armed else 0.0
            for j in range(4):
                lg[k, 13 + j] = mo[j]
                lg[k, 18 + j] = chi[j] if (armed and diag_mask[2]) else nan
                lg[k, 22 + j] = sg[j] if (armed and diag_mask[1]) else nan
                lg[k, 26 + j] = sv[j] if (armed and diag_mask[0]) else nan
                lg[k, 30 + j] = uu[j]
                lg[k, 34 + j] = rf[j]
                lg[k, 38 + j] = mo[j]
            lg[k, 42] = tx
            lg[k, 43] = ty
            lg[k, 44] = tz
            lg[k, 45] = yaw_target
            lim = out[2]
            lg[k, 46] = (1.0 if lim[0] else 0.0) + (2.0 if lim[1] else 0.0) + (4.0 if lim[2] else 0.0) + (8.0 if lim[3] else 0.0)
            lg[k, 47] = flags
            lg[k, 48] = mode_num
            # the IMU and the truth the simulator sends with the state (HIGHRES_IMU, ODOMETRY)
            lg[k, 49] = fa[0]
            lg[k, 50] = fa[1]
            lg[k, 51] = fa[2]
            lg[k, 52] = x
            lg[k, 53] = y
            lg[k, 54] = z
            lg[k, 55] = vx
            lg[k, 56] = vy
            lg[k, 57] = vz
            lg[k, 58] = qw
            lg[k, 59] = qx
            lg[k, 60] = qy
            lg[k, 61] = qz
            lg[k, 62] = p_
            lg[k, 63] = q_
            lg[k, 64] = r_
        # -- the physics: sub-steps with the motor commands held --------------------------------
        t_tick = t_us
        targets = rigid_body_targets((m0, m1, m2, m3), armed, rbp)
        s = (x, y, z, vx, vy, vz, qw, qx, qy, qz, p_, q_, r_, w1, w2, w3, w4)
        u_in = (eff, paper, turns)
        for _i in range(substeps):
            t = t_us * 1e-6
            fx = wind[0]
            fy = wind[1]
            fz = wind[2]
            tqx = 0.0
            tqy = 0.0
            tqz = 0.0
            if gusts_on:
                if dt_phys != last_h:
                    ga = _exp(-dt_phys / g_tau)
                    gb = _sqrt(max(0.0, 1.0 - ga * ga))
                    last_h = dt_phys
                mt_gauss_fill(gmt, ggs, zb, n_gust)
                jz = 0
                for j in range(6):
                    sd = gust_std[j]
                    if sd > 0.0:
                        gust[j] = ga * gust[j] + gb * (0.0 + zb[jz] * sd)
                        jz += 1
                fx = wind[0] + gust[0]
                fy = wind[1] + gust[1]
                fz = wind[2] + gust[2]
                tqx = gust[3]
                tqy = gust[4]
                tqz = gust[5]
            if n_fg > 0:
                # the faults' gusts (sim_bridge.faults.SimFaults.advance): NED force, FRD torque
                gfn = 0.0
                gfe = 0.0
                gtx = 0.0
                gty = 0.0
                gtz = 0.0
                mt_gauss_fill(fgmt, fggs, zb, n_fgz)
                jz = 0
                for gi in range(n_fg):
                    if dt_phys != fg[gi, 8]:
                        fg[gi, 9] = _exp(-dt_phys / fg[gi, 7])
                        fg[gi, 10] = _sqrt(max(0.0, 1.0 - fg[gi, 9] * fg[gi, 9]))
                        fg[gi, 8] = dt_phys
                    a_ = fg[gi, 9]
                    b_ = fg[gi, 10]
                    f_sd = fg[gi, 5]
                    if f_sd > 0.0:
                        fg[gi, 0] = a_ * fg[gi, 0] + b_ * (0.0 + zb[jz] * f_sd)
                        fg[gi, 1] = a_ * fg[gi, 1] + b_ * (0.0 + zb[jz + 1] * f_sd)
                        jz += 2
                    t_sd = fg[gi, 6]
                    if t_sd > 0.0:
                        fg[gi, 2] = a_ * fg[gi, 2] + b_ * (0.0 + zb[jz] * t_sd)
                        fg[gi, 3] = a_ * fg[gi, 3] + b_ * (0.0 + zb[jz + 1] * t_sd)
                        fg[gi, 4] = a_ * fg[gi, 4] + b_ * (0.0 + zb[jz + 2] * t_sd)
                        jz += 3
                    gfn += fg[gi, 0]
                    gfe += fg[gi, 1]
                    gtx += fg[gi, 2]
                    gty += fg[gi, 3]
                    gtz += fg[gi, 4]
                fx = fx + (fault_force[0] + gfn)
                fy = fy + (fault_force[1] + -gfe)
                fz = fz + (fault_force[2] + -0.0)
                tqx = tqx + (fault_torque[0] + gtx)
                tqy = tqy + (fault_torque[1] + -gty)
                tqz = tqz + (fault_torque[2] + -gtz)
            elif add_forces:
                fx = fx + fault_force[0]
                fy = fy + fault_force[1]
                fz = fz + fault_force[2]
                tqx = tqx + fault_torque[0]
                tqy = tqy + fault_torque[1]
                tqz = tqz + fault_torque[2]
            s, accel, ok = rigid_body_substep_lag(s, targets, (fx, fy, fz), (tqx, tqy, tqz), t, dt_phys, rbp, u_in, e_half, psi_s)
            if not ok:
                io_f[0] = t + dt_phys
                t_us = t_tick  # the tick whose physics diverged (it counts as flown by the FC)
                code = 2
                break
            psi1, turns1 = heading_turns(s, psi0, turns)
            psi_s = psi1
            if turns1 != turns:
                turns = turns1
                u_in = (eff, paper, turns)
            psi0 = psi1
            acc_x = accel[0]
            acc_y = accel[1]
            acc_z = accel[2]
            plant_f[5] = t + dt_phys
            t_us += step_us
        for j in range(17):
            plant_s[j] = s[j]
        if code == 2:
            break
        k += 1
    plant_f[0] = psi0
    plant_f[1] = turns
    plant_f[2] = acc_x
    plant_f[3] = acc_y
    plant_f[4] = acc_z
    env_f[0] = last_h
    env_f[1] = ga
    env_f[2] = gb
    io[0] = k
    io[1] = code
    io[2] = n_rec
    io[3] = t_us
    io[4] = n_missing
    io[5] = n_dr
    io[6] = last_missing
    io_f[1] = ground_s
    return ps, es, out, est


#: the law's functions (:class:`fc.control.law.LawFunctions`) the kernel calls: rebound per law
#: when the kernel is compiled (:func:`lab.fast.flight.compiled_kernel`); never set here, as the
#: kernel only ever flies compiled.
_LAW = None


def _kernel_law():  # type: ignore[no-untyped-def]
    """The law's functions the kernel calls: :data:`_LAW`, which the compiled kernel (one per law)
    holds as constants. So it calls them directly, with no C wrapper and indirect call as for
    functions handed to it. Inlined, never a value of its own: a tuple of compiled functions
    made a value would carry their addresses, and numba cannot cache code that does."""
    return _LAW


#: the kernel and what it calls of its own (compiled with the pipeline's, the estimate's, the
#: plant's and the random streams' pure functions: :data:`lab.fast.flight.KERNEL_FUNCTIONS`).
KERNEL_FUNCTIONS = (fly_span, _sensed_none, _sensed_imu, _noisy3, _noise_draws, _watch_holds, _f32, _f32_overflows, _kernel_law)

#: what the kernel calls for a tick's sensed quantities (rebound for a law that measures acceleration).
_sensed = _sensed_none
