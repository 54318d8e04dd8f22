"""The paper's model against the emulated vehicle in every motion mode: the emulator's motion satisfies
the constraints (1) and the kinematic model (4), mode detection (9) recognises its configurations, and
the feed-forward law (21) with the true parameters is the torque it needs to follow a trajectory."""
import math

import numpy as np
import pytest

from qomni.emulator.description import VehicleDescription
from qomni.emulator.vehicle import Emulator
from qomni.ident import dynamics, kinematics
from qomni.datasheet import Geometry

D = VehicleDescription.load()
G = Geometry(D.geometry.l, D.geometry.b, D.geometry.a, D.geometry.r, D.geometry.steering_limit)
I_G = D.drive.i_G
P_TRUE = np.array([getattr(D.truth, n) for n in
                   ("C_l", "d_vl", "d_cl", "C_r", "d_vr", "d_cr", "m_ch", "C_ch", "d_vw", "d_cw", "B_w")])
TS = D.drive.cycle_time
THETA4 = math.atan(G.l / G.b)


def qdot_of(state) -> np.ndarray:
    return np.concatenate([state.velocity, state.alpha_dot, state.beta_dot])


def profile(t: np.ndarray, duration: float, peak: float):
    """Rest-to-rest velocity sin²(πt/T)·peak with its acceleration."""
    v = peak * np.sin(np.pi * t / duration) ** 2
    a = peak * np.pi / duration * np.sin(2 * np.pi * t / duration)
    return v, a


def lateral_allocation(q, sd, sdd) -> np.ndarray:
    """Mode 3: H_3ᵀB is (H_1ᵀB rows summed)/a, so every lateral drive torque also steers. The wheels
    are held only by the stops at ±π/2: the side whose steering torque presses into its stop takes
    the whole generalized force — the right side for a force towards +y, the left side towards −y —
    and the other side idles. The generalized force itself is (19)'s H_3ᵀΘp."""
    theta = dynamics.reduced_regressor(3, q, *dynamics.generalized_state(3, q, sd, sdd, G), G)
    q_y = float((theta[0] @ P_TRUE)[0])
    m = q_y * G.r / (2 * I_G)  # Q_y = (i_G/r)(M_fr − M_rr) = (i_G/r)(M_rl − M_fl)
    return np.array([0.0, 0.0, m, -m]) if q_y >= 0 else np.array([-m, m, 0.0, 0.0])


# (mode, initial α, generalized velocity profile: index of ṡ excited, peak, duration)
CASES = {
    1: ((0.2, -0.3), 0, 0.8, 1.5),
    2: (tuple(kinematics.f_icr(np.array([0.15]), G)[0]), 1, 0.6, 2.0),
    3: ((-math.pi / 2, math.pi / 2), 0, 0.4, 2.0),
    4: ((-THETA4, THETA4), 0, 0.6, 2.0),
}


@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_feedforward_drives_the_emulator_along_the_mode(k):
    alpha0, index, peak, duration = CASES[k]
    n_s = kinematics.H(k, np.array([alpha0]), G).shape[2]
    hold = k in (2, 4)
    with Emulator(D, seed=11, initial_alpha=alpha0) as emu:
        assert kinematics.motion_mode(emu.true_state().alpha[None], G, tol=2e-3)[0] == k
        times = np.arange(0, duration, TS)
        achieved, planned, residual = [], [], []
        for t in times:
            state = emu.true_state()
            v, a = profile(np.array([t]), duration, peak)
            sd, sdd = np.zeros((1, n_s)), np.zeros((1, n_s))
            sd[0, index], sdd[0, index] = v[0], a[0]
            q = np.zeros((1, 9))
            q[0, 3:5] = alpha0
            u = dynamics.feedforward(k, q, sd, sdd, P_TRUE, G, I_G)[0]
            if k == 3:
                u = lateral_allocation(q, sd, sdd)
            elif hold:  # steering hold through differential wheel torques (H_1ᵀB), stiff PD
                error = np.array(alpha0) - state.alpha
                q_hold = 0.5 * (3000.0 * error - 80.0 * state.alpha_dot)
                rows = I_G * kinematics.H(1, np.zeros((1, 2)), G)[0][5:9, :].T
                u = u + np.linalg.pinv(rows) @ q_hold
            emu.set_motor_torques(u)
            emu.step(TS)
            after = emu.true_state()
            qd = qdot_of(after)
            residual.append(np.abs(kinematics.constraint_matrix(after.alpha[None], G)[0] @ qd).max())
            sd_meas = kinematics.sdot_from_qdot(k, after.alpha[None], qd[None], G)[0]
            achieved.append(sd_meas[index])
            planned.append(profile(np.array([t + TS]), duration, peak)[0][0])
        achieved, planned = np.array(achieved), np.array(planned)
        # feed-forward alone (no feedback on ṡ) reproduces the planned velocity profile
        assert np.max(np.abs(achieved - planned)) < 0.05 * peak, k
        # the emulator's motion satisfies the rolling constraints (1) up to tire compliance
        speed = max(peak, 1e-9)
        assert np.percentile(residual, 95) < 0.01 * speed * max(1.0, G.l), k
        assert kinematics.motion_mode(emu.true_state().alpha[None], G, tol=5e-3)[0] == k


@pytest.mark.parametrize("k", [1, 2, 4])
def test_emulator_velocity_lies_in_the_range_of_H(k):
    """q̇ of the emulator equals H_k(α) ṡ_k with ṡ_k from its own velocities (4)."""
    alpha0 = CASES[k][0]
    u = {1: [-0.8, 0.8, 0.9, -0.9],  # above breakaway (d_c + wheel friction ≈ 19 N m per side)
          2: [0.6, 0.6, 0.6, 0.6], 4: [-0.5, -0.5, 0.5, 0.5]}[k]
    with Emulator(D, seed=12, initial_alpha=alpha0) as emu:
        emu.set_motor_torques(u)
        emu.step(0.2 if k == 1 else 0.5)
        st = emu.true_state()
    qd = qdot_of(st)
    alpha = st.alpha[None] if k == 1 else np.array([alpha0])
    sd = kinematics.sdot_from_qdot(k, alpha, qd[None], G)
    reconstructed = (kinematics.H(k, alpha, G) @ sd[..., None])[0, :, 0]
    assert np.linalg.norm(reconstructed - qd) < 0.02 * np.linalg.norm(qd)
