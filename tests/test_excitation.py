"""Tests for ident.fourier (rest-to-rest Fourier design) and ident.excitation (the paper's steps, section 6.2)."""

import math

import numpy as np
import pytest

from qomni.ident import excitation as ex
from qomni.ident import fourier

L, B, A = 1.2, 0.9, 0.08


def _dense(tr, n=30001):
    t = np.linspace(0.0, tr.duration, n)
    return (t, *tr.evaluate(t))


def test_fourier_rest_to_rest_and_derivatives():
    tr = fourier.design_fourier_trajectory(duration=3.0, q_min=-0.5, q_max=0.5, qd_max=1.0, qdd_max=5.0, seed=7)
    t, q, qd, qdd = _dense(tr)
    assert abs(q[0]) < 1e-12 and abs(q[-1]) < 1e-9
    for v in (qd[0], qd[-1], qdd[0], qdd[-1]):
        assert abs(v) < 1e-9
    # analytic derivatives match numerical ones
    dt = t[1] - t[0]
    assert np.allclose(np.gradient(q, dt, edge_order=2), qd, atol=1e-5 * np.max(np.abs(qd)))
    assert np.allclose(np.gradient(qd, dt, edge_order=2), qdd, atol=1e-4 * np.max(np.abs(qdd)))
    # at rest outside [0, T]
    q_out, qd_out, qdd_out = tr.evaluate(np.array([-1.0, tr.duration + 1.0]))
    assert np.allclose(q_out, tr.q_start) and not qd_out.any() and not qdd_out.any()


def test_fourier_rejects_coefficients_not_at_rest():
    with pytest.raises(ValueError, match="rest conditions"):
        fourier.FourierTrajectory(omega_f=1.0, a=[1.0, 0.0], b=[0.0, 0.0])
    a, b = fourier.FourierTrajectory.project_to_rest([1.0, 0.3, -0.2], [0.5, 0.1, 0.4])
    tr = fourier.FourierTrajectory.from_start(2.0, a, b, q_start=0.2)
    assert abs(tr.position(0.0) - 0.2) < 1e-12 and abs(tr.position(tr.duration) - 0.2) < 1e-12
    back = fourier.FourierTrajectory.from_json_dict(tr.to_json_dict())
    assert np.array_equal(back.a, tr.a) and np.array_equal(back.b, tr.b) and back.q0 == tr.q0


@pytest.mark.parametrize("offset", [0.0, 0.3])
def test_design_respects_limits(offset):
    lim = dict(q_min=-0.6 + offset, q_max=0.6 + offset, qd_max=0.8, qdd_max=3.0)
    tr = fourier.design_fourier_trajectory(duration=2.5, q_start=offset, seed=3, **lim)
    _, q, qd, qdd = _dense(tr)
    assert q.min() >= lim["q_min"] - 1e-9 and q.max() <= lim["q_max"] + 1e-9
    assert np.max(np.abs(qd)) <= lim["qd_max"] + 1e-9
    assert np.max(np.abs(qdd)) <= lim["qdd_max"] + 1e-9
    # at least one limit is (nearly) active: the trajectory is scaled to the limits
    util = max(
        (q.max() - offset) / (lim["q_max"] - offset),
        (offset - q.min()) / (offset - lim["q_min"]),
        np.max(np.abs(qd)) / lim["qd_max"],
        np.max(np.abs(qdd)) / lim["qdd_max"],
    )
    assert util > 0.98


def test_design_deterministic():
    kw = dict(duration=15.0, q_min=-1.0, q_max=1.0, qd_max=1.0, qdd_max=4.0)
    a = fourier.design_fourier_trajectory(seed=11, **kw)
    b = fourier.design_fourier_trajectory(seed=11, **kw)
    c = fourier.design_fourier_trajectory(seed=12, **kw)
    assert np.array_equal(a.a, b.a) and np.array_equal(a.b, b.b)
    assert not np.allclose(a.a, c.a)


def test_design_invalid_limits():
    with pytest.raises(ValueError):
        fourier.design_fourier_trajectory(duration=2.0, q_min=0.0, q_max=1.0, qd_max=1.0, qdd_max=1.0)
    with pytest.raises(ValueError):
        fourier.design_fourier_trajectory(duration=2.0, q_min=-1.0, q_max=1.0, qd_max=0.0, qdd_max=1.0)


def test_campaign_steps():
    steps = ex.identification_campaign(l=L, b=B, duration=2.0, x_max=0.5, gamma_max=0.4)
    assert [s.name for s in steps] == ["steer_left", "steer_right", "straight", "rotation"]
    assert [s.mode for s in steps] == [1, 1, 2, 4]
    assert steps[0].channels == ("steer_left/alpha_l",)
    assert steps[2].channels == ("straight/x_ch",)
    t = steps[0].time(2e-3)
    d = steps[0].evaluate(t)
    assert set(d) == {"alpha_l", "alpha_r"} and not d["alpha_r"][0].any()
    q = d["alpha_l"][0]
    assert np.max(np.abs(q)) <= ex.ALPHA_MAX_DEFAULT + 1e-9 and np.max(np.abs(q)) > 0.1
    x = steps[2].evaluate(steps[2].time())["x_ch"][0]
    assert np.max(np.abs(x)) <= 0.5 + 1e-9
    d4 = steps[3].evaluate(np.array([0.5]))
    assert np.isclose(d4["alpha_l"][0][0], -math.atan(L / B)) and np.isclose(d4["alpha_r"][0][0], math.atan(L / B))
    assert np.max(np.abs(steps[3].evaluate(steps[3].time())["gamma_ch"][0])) <= 0.4 + 1e-9
    with pytest.raises(TypeError):
        ex.identification_campaign(l=L, b=B, duration=2.0, bogus=1.0)


def test_lane_change():
    step = ex.lane_change(l=L, duration=3.0, distance=2.0, lane_width=0.5, x_dot_max=2.0)
    assert step.mode == 2 and set(step.channels) == {"lane_change/alpha_v", "lane_change/x_ch"}
    t = np.linspace(0.0, step.duration, 6001)
    d = step.evaluate(t)
    av, avd, avdd = d["alpha_v"]
    x, xd, xdd = d["x_ch"]
    for v in (av[0], av[-1], avd[0], avd[-1], avdd[0], avdd[-1], xd[0], xd[-1], xdd[0], xdd[-1], x[0]):
        assert abs(v) < 1e-9
    assert np.isclose(x[-1], 2.0)
    dt = t[1] - t[0]
    assert np.allclose(np.gradient(x, dt, edge_order=2), xd, atol=1e-4)
    assert np.allclose(np.gradient(av, dt, edge_order=2), avd, atol=1e-4)
    assert np.allclose(np.gradient(avd, dt, edge_order=2), avdd, atol=1e-3)
    _, y_w, gamma = ex.mode2_path(t, xd, av, L)
    assert abs(y_w[-1] - 0.5) < 1e-4 and abs(gamma[-1]) < 1e-9
    with pytest.raises(ValueError):
        ex.lane_change(l=L, duration=3.0, distance=2.0, x_dot_max=1.0)
    with pytest.raises(ValueError, match="not reachable"):
        ex.lane_change(l=L, duration=3.0, distance=1.0, lane_width=5.0)


def test_a_lane_change_a_longer_vehicle_cannot_steer_is_narrowed_to_its_steering_limits():
    """The quick campaign's double lane change (0.1 m over 3 m in 8 s) steers at up to 1.16 rad/s on the
    prototype (l = 1.2 m) and would need 1.89 rad/s on a vehicle of l = 2 m, where the campaign allows
    1.5 (and 6 rad/s²): narrowed, it reaches the tighter of the two limits and no further (up to the
    peaks' sampling, 10⁻⁴), on a narrower lane that still returns to its own;
    where the limits do not bind it is the lane change as asked. Beyond |α_v| ≤ 0.6 rad (l = 4 m) it is
    the widest lane that angle reaches."""
    limits = dict(alpha_v_max=0.6, alpha_dot_max=1.5, alpha_ddot_max=6.0)
    ask = dict(duration=8.0, distance=3.0, lane_width=0.1, changes=2, **limits)
    t = np.linspace(0.0, 8.0, 8001)

    def drive(step, l):
        d = step.evaluate(t)
        av, avd, avdd = d["alpha_v"]
        _, y_w, gamma = ex.mode2_path(t, d["x_ch"][1], av, l)
        return np.abs(av).max(), np.abs(avd).max(), np.abs(avdd).max(), np.abs(y_w).max(), y_w[-1], gamma[-1]

    with pytest.raises(ValueError, match="alpha_dot_v"):
        ex.lane_change(l=2.0, **ask)
    prototype = ex.lane_change(l=1.2, **ask)
    for key in ("alpha_v", "x_ch"):
        np.testing.assert_array_equal(ex.lane_change(l=1.2, narrow_to_limits=True, **ask).evaluate(t)[key],
                                      prototype.evaluate(t)[key])
    assert drive(prototype, 1.2)[3] == pytest.approx(0.1, abs=1e-4)
    peak_a, peak_ad, peak_add, width, end, heading = drive(ex.lane_change(l=2.0, narrow_to_limits=True, **ask),
                                                           2.0)
    assert max(peak_ad / 1.5, peak_add / 6.0) == pytest.approx(1.0, abs=2e-3)
    assert peak_ad <= 1.5 * (1 + 1e-4) and peak_add <= 6.0 * (1 + 1e-4) and 0.05 < width < 0.1
    assert abs(end) < 1e-6 and abs(heading) < 1e-9
    peak_a, peak_ad, peak_add, width, end, heading = drive(ex.lane_change(l=4.0, narrow_to_limits=True, **ask),
                                                           4.0)
    assert peak_a <= 0.6 + 1e-9 and peak_ad <= 1.5 * (1 + 1e-4) and peak_add <= 6.0 * (1 + 1e-4)
    assert 0 < width < 0.1


def test_a_double_lane_change_returns_to_its_lane_and_steers_above_stiction():
    """Two changes along the way: out by the lane width and back, heading 0 at the end; over the same way
    the steering moves faster than the single change's and |α̇_v| stays above 0.2 rad/s for a real share."""
    kw = dict(l=L, duration=12.0, distance=4.5, lane_width=0.25, alpha_v_max=0.6, alpha_dot_max=2.5,
              alpha_ddot_max=10.0)
    t = np.linspace(0.0, 12.0, 12001)
    double, single = (ex.lane_change(changes=n, **kw).evaluate(t) for n in (2, 1))
    av, avd, avdd = double["alpha_v"]
    x, xd, _ = double["x_ch"]
    for v in (av[0], av[-1], avd[0], avd[-1], avdd[0], avdd[-1]):
        assert abs(v) < 1e-9
    dt = t[1] - t[0]
    assert np.allclose(np.gradient(av, dt, edge_order=2), avd, atol=1e-4)
    # C² where the changes join (α̈ = 0 there, the jerk changes sign): one central difference off by dt·jerk
    assert np.allclose(np.gradient(avd, dt, edge_order=2), avdd, atol=5e-3)
    _, y_w, gamma = ex.mode2_path(t, xd, av, L)
    assert abs(np.max(np.abs(y_w)) - 0.25) < 1e-6 and abs(y_w[-1]) < 1e-3 and abs(gamma[-1]) < 1e-6
    assert np.mean(np.abs(avd) > 0.2) >= 0.35 > np.mean(np.abs(single["alpha_v"][1]) > 0.2)
    with pytest.raises(ValueError, match="alpha_dot"):
        ex.lane_change(**{**kw, "alpha_dot_max": 0.5}, changes=2)
    with pytest.raises(ValueError, match="changes"):
        ex.lane_change(**kw, changes=0)


@pytest.mark.parametrize("side", [1, -1])
def test_an_arc_holds_the_mode_2_configuration_with_its_inner_units_at_the_given_angle(side):
    from qomni.datasheet import DataSheet
    from qomni.ident import kinematics

    geometry = DataSheet.load().geometry
    step = ex.arc_excitation(l=L, b=B, side=side, inner_alpha=1.25, duration=10.0, gamma_max=1.0,
                             gamma_dot_max=0.8, gamma_ddot_max=3.0, x_ddot_max=1.6, n_harmonics=5,
                             periods=2, seed=9)
    assert step.name == ("arc_left" if side > 0 else "arc_right") and step.mode == 2
    held = step.held
    alpha = np.array([held["alpha_l"], held["alpha_r"]])
    # on the ICR manifold (8), turning to ``side``, the inner unit at 1.25 rad
    assert np.allclose(kinematics.f_icr(held["alpha_v"], geometry)[0], alpha, atol=1e-12)
    assert np.sign(held["alpha_v"]) == side and max(abs(alpha)) == pytest.approx(1.25, abs=1e-12)
    kappa = abs(math.tan(held["alpha_v"])) / (L / 2)
    t, x, xd, xdd = _dense(step.trajectories["x_ch"])
    assert abs(x[0]) < 1e-12 and abs(x[-1]) < 1e-9 and abs(xd[-1]) < 1e-9
    assert np.max(np.abs(x)) * kappa <= 1.0 and np.max(np.abs(xd)) * kappa <= 0.8
    assert np.max(np.abs(xdd)) <= 1.6 + 1e-9 and np.max(np.abs(xdd)) > 1.0   # the yaw bound, 3/κ, is wider
    with pytest.raises(ValueError, match="side"):
        ex.arc_excitation(l=L, b=B, side=0)
    with pytest.raises(ValueError, match="inner_alpha"):
        ex.arc_excitation(l=L, b=B, side=side, inner_alpha=math.pi / 2)


def test_the_campaign_plans_its_arcs_inside_the_stops_or_not_at_all():
    """The prototype's arcs put the inner units at 1.25 rad, 0.32 rad inside its stops at π/2; a vehicle
    whose stops are at ±1.2 rad drives its arcs 0.32 rad inside those, and one whose rotation (mode 4)
    would need its units at the stops has no campaign."""
    from dataclasses import replace

    from qomni.datasheet import DataSheet
    from qomni.ident.campaign import ARC_STEPS, ARC_STOP_CLEARANCE, CampaignSettings, arc_inner_angle, plan

    sheet = DataSheet.load()
    assert [s.name for s in plan(sheet, CampaignSettings())][-2:] == list(ARC_STEPS)
    assert not set(ARC_STEPS) & {s.name for s in plan(sheet, CampaignSettings(arc_duration=0.0))}
    assert arc_inner_angle(CampaignSettings(), sheet.geometry) == 1.25
    tight = replace(sheet, geometry=replace(sheet.geometry, steering_limit=1.2))
    assert arc_inner_angle(CampaignSettings(), tight.geometry) == pytest.approx(1.2 - ARC_STOP_CLEARANCE)
    for settings in (CampaignSettings(), CampaignSettings.quick()):
        steps = {s.name: s for s in plan(tight, settings)}
        for name in ARC_STEPS:
            held = steps[name].held
            assert max(abs(held["alpha_l"]), abs(held["alpha_r"])) == pytest.approx(1.2 - ARC_STOP_CLEARANCE)
    square = replace(sheet, geometry=replace(sheet.geometry, l=1.0, b=0.5, steering_limit=1.1))
    with pytest.raises(ValueError, match=r"rotation \(mode 4\) holds the steering units at ±1.107 rad"):
        plan(square, CampaignSettings())
    with pytest.raises(ValueError, match="no room"):
        plan(replace(sheet, geometry=replace(sheet.geometry, l=0.2, b=1.0, steering_limit=0.3)),
             CampaignSettings())


def test_occupied_rectangle():
    length, width = ex.occupied_rectangle(np.array([0.0, 0.7, -1.1, 0.2]), L, B, A)
    assert np.isclose(length, L + 2.2) and np.isclose(width, math.hypot(L, B) + 2 * A)
    step = ex.straight_excitation(duration=2.0, x_max=0.4)
    length, _ = ex.occupied_rectangle(step.trajectories["x_ch"], L, B, A)
    assert L < length <= L + 0.8 + 1e-9
