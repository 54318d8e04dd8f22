"""The Stribeck hypothesis' friction direction where a joint sticks, checked on a simulated stick-slip
joint (static friction ratio·d_c decaying to d_c over v_s, as the emulator's joints have)."""
import numpy as np
import pytest

from qomni.conventions import EPSILON as EPS_SIGN
from qomni.diagnosis.hypotheses.stribeck import STICK_VELOCITY, _friction_direction, _stribeck
from qomni.ident import filtering

T_S = 0.002
J, D_C, V_S = 0.5, 2.0, 0.05  # kg m², N m, rad/s


def test_a_sticking_joint_is_pushed_the_way_it_then_moves():
    v = np.array([0.5, 0.2, 0.005, 0.0, -0.003, -0.3, -0.5, 0.001, 0.0])[:, None]
    direction = _friction_direction(v)[:, 0]
    assert direction[:2] == pytest.approx(np.tanh(v[:2, 0] / EPS_SIGN))
    # stuck between the positive and the negative motion: the negative motion ends the stick
    assert np.all(direction[2:5] == -1.0)
    assert direction[5:7] == pytest.approx(-1.0)
    # stuck at the end with no motion after it: the motion before it
    assert np.all(direction[7:] == -1.0)
    assert abs(v[2, 0]) < STICK_VELOCITY < abs(v[1, 0])


def test_a_joint_that_never_slides_has_no_direction():
    v = np.zeros((5, 2))
    assert np.all(_friction_direction(v) == 0.0)


def _stick_slip_residual(ratio: float, u: np.ndarray):
    """Filtered speed and the residual the paper's model (J, d_c·tanh(v/ε)) leaves on a joint whose
    static friction is ratio·d_c, decaying to d_c over V_S; integrated at T_S/5."""
    v, speed, sub = np.zeros(len(u)), 0.0, 5
    for k, torque in enumerate(u):
        for _ in range(sub):
            limit = D_C * (1 + (ratio - 1) * np.exp(-(speed / V_S) ** 2))
            if speed == 0.0 and abs(torque) <= limit:
                friction = torque
            else:
                friction = limit * np.sign(speed if speed != 0 else torque)
            new = speed + T_S / sub * (torque - friction) / J
            speed = 0.0 if speed != 0 and np.sign(new) != np.sign(speed) else new
        v[k] = speed
    lowpass = lambda x: filtering.zero_phase_lowpass(x, T_S)  # noqa: E731
    v_f = lowpass(v)
    residual = lowpass(u) - J * lowpass(np.gradient(v, T_S)) - D_C * lowpass(np.tanh(v_f / EPS_SIGN))
    return v_f, residual, lowpass


def _fit(column, residual, rows):
    theta = column[rows] @ residual[rows] / (column[rows] @ column[rows])
    error = residual - theta * column
    return theta, 1 - error[rows].var() / residual[rows].var()


def test_the_column_follows_the_breakaway_ratio_through_the_stick_slip_transients():
    t = np.arange(6000) * T_S
    u = 5.0 * np.sin(2 * np.pi * 0.25 * t) + 1.5 * np.sin(2 * np.pi * 0.9 * t)
    fitted = {}
    for ratio in (1.0, 2.0):
        v_f, residual, lowpass = _stick_slip_residual(ratio, u)
        moving = np.abs(v_f) > 0.05  # the rows a torque channel fits
        column = lowpass(D_C * _stribeck(v_f[:, None], V_S)[:, 0])
        sliding_sign = lowpass(D_C * np.exp(-(v_f / V_S) ** 2) * np.tanh(v_f / EPS_SIGN))
        fitted[ratio] = _fit(column, residual, moving)
        # the sign of the filtered speed alone misses the transients that leak out of the stuck rows
        assert fitted[ratio][1] > 2 * _fit(sliding_sign, residual, moving)[1]
    # beyond the level of a joint without a peak (the reference run's), the excess ratio − 1 = 1
    excess = fitted[2.0][0] - fitted[1.0][0]
    assert 0.5 < excess < 2.0
    assert fitted[2.0][1] > 0.2
