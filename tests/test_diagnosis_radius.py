"""The wheel-radius hypothesis' torque column against the paper's model (19) of a vehicle whose wheels
are smaller than the data sheet says: the true vehicle's input (feed-forward (21) at the true radius),
read as the diagnosis reads a run (joint angles exact, chassis motion from odometry (3) at the nominal
radius), leaves a residual that ε times the column predicts to first order in ε = r_nominal/r − 1."""
import dataclasses
import math
from types import SimpleNamespace as NS

import numpy as np
import pytest

from qomni.diagnosis.hypotheses.wheel_radius import WHEEL_RADIUS
from qomni.diagnosis.hypotheses.base import _input_torque, _project
from qomni.emulator.description import VehicleDescription
from qomni.ident import dynamics, kinematics, odometry
from qomni.datasheet import Geometry

D = VehicleDescription.load()
G = Geometry(D.geometry.l, D.geometry.b, D.geometry.a, D.geometry.r, D.geometry.steering_limit)
I_G = D.drive.i_G
P = np.array([getattr(D.truth, n) for n in
              ("C_l", "d_vl", "d_cl", "C_r", "d_vr", "d_cr", "m_ch", "C_ch", "d_vw", "d_cw", "B_w")])
TS = 0.004


def _trajectory(k: int):
    """(q, ṡ, s̈) of a smooth 4 s motion in mode k: reversing, so friction and inertia both show."""
    t = np.arange(0.0, 4.0, TS)
    w = 2 * math.pi / 4.0
    amp = {1: 0.4, 3: 0.5, 4: 0.4}[k]
    sd = amp * np.sin(w * t)[:, None]
    sdd = amp * w * np.cos(w * t)[:, None]
    q = np.zeros((len(t), 9))
    if k == 1:   # the left side steers, the right one is held
        sd, sdd = np.hstack([sd, 0 * sd]), np.hstack([sdd, 0 * sdd])
        q[:, 3] = amp / w * (1 - np.cos(w * t))
    else:
        q[:, 3:5] = kinematics.mode_alpha(k, G)
    return q, sd, sdd


def _read_with_nominal_radius(k: int, r_true: float):
    """(Θ̂ (N, n_k, 11), τ̂ (N, n_k)) of the true vehicle's motion and input as odometry at G.r sees it."""
    q, sd, sdd = _trajectory(k)
    true = dataclasses.replace(G, r=r_true)
    u = dynamics.feedforward(k, q, sd, sdd, P, true, I_G)
    qd, qdd = dynamics.generalized_state(k, q, sd, sdd, true)
    chassis = odometry.chassis_velocity(q[:, 3:5], qd[:, 3:5], qd[:, 5:9], G)
    qd_read = np.hstack([chassis, qd[:, 3:]])
    qdd_read = np.hstack([np.gradient(chassis, TS, axis=0, edge_order=2), qdd[:, 3:]])
    return (dynamics.reduced_regressor(k, q, qd_read, qdd_read, G),
            dynamics.reduced_input(k, q, u, G, I_G), q, u)


def _channel(k, theta, q, u):
    """The first coordinate's torque channel as the hypotheses read it (every row kept)."""
    st = NS(motor_torque=u, time=np.arange(len(q)) * TS)
    return NS(kind="torque", base=theta[:, 0, :10], index=0, rows=lambda x: x,
              context=NS(p=P, st=st, H=kinematics.H(k, q[:, 3:5], G), sheet=NS(drive=NS(i_G=I_G)), lifted=False),
              held_out_only=False)


@pytest.mark.parametrize("k", [1, 3, 4])
def test_the_radius_column_is_the_residual_odometrys_scale_leaves_to_first_order(k):
    r_true = 0.96 * G.r
    eps = G.r / r_true - 1
    theta, tau, q, u = _read_with_nominal_radius(k, r_true)
    ch = _channel(k, theta, q, u)
    residual = tau[:, 0] - theta[:, 0, :] @ P
    column = WHEEL_RADIUS.columns(ch, None)[:, 0]
    lever = -_project(ch, _input_torque(ch))   # the input lever the column replaced
    rel = lambda c: float(np.linalg.norm(residual - eps * c) / np.linalg.norm(residual))  # noqa: E731
    assert np.linalg.norm(residual) > 1e-3 * np.linalg.norm(tau[:, 0])   # the effect is there
    assert rel(column) < 2 * eps      # measured ε (mode 1) and 1.5 ε (3, 4): (1 + ε)⁻² = 1 − 2ε + 3ε² …
    assert rel(lever) > 0.3           # 48–87 %: the lever also scales the wheels' friction


def test_the_columns_error_is_second_order_in_the_radius_error():
    errors = []
    for scale in (0.98, 0.96):
        r_true = scale * G.r
        eps = G.r / r_true - 1
        theta, tau, q, u = _read_with_nominal_radius(4, r_true)
        residual = tau[:, 0] - theta[:, 0, :] @ P
        column = WHEEL_RADIUS.columns(_channel(4, theta, q, u), None)[:, 0]
        errors.append(float(np.linalg.norm(residual - eps * column) / np.linalg.norm(residual)))
    assert errors[1] == pytest.approx(2 * errors[0], rel=0.25)   # relative error ∝ ε
