"""The campaign controller's cycle: references and feed-forward planned per step, the mode-2 allocation
cached by the measured steering counts. Both must command what evaluating everything at the cycle would."""
import numpy as np
import pytest

from qomni.datasheet import DataSheet
from qomni.ident.campaign import Campaign, CampaignSettings
from qomni.ident.controller import StepController
from qomni.ident.excitation import straight_excitation
from qomni.vehicle_interface import Measurement

SHEET = DataSheet.load()


@pytest.fixture(scope="module")
def controllers(tmp_path_factory):
    campaign = Campaign(SHEET, tmp_path_factory.mktemp("plan") / "run", CampaignSettings.quick())
    return {seg.name: ctrl for seg, ctrl in zip(campaign.segments, campaign.controllers)}


def _feedforward_at(ctrl: StepController, t: float) -> np.ndarray:
    """The feed-forward (21) evaluated for the single time t, as the cycle did before planning."""
    a, ad, add, chassis, av = ctrl._references(np.array([t]))
    return ctrl._feedforward(a, ad, add, chassis, av)[0]


@pytest.mark.parametrize("name", ["steer_left", "straight", "rotation", "lane_change"])
def test_the_planned_feedforward_is_the_one_evaluated_at_each_cycle(controllers, name):
    ctrl = controllers[name]
    ts = SHEET.drive.cycle_time
    for j in np.linspace(0, ctrl.cycles - 1, 25).astype(int):
        row = ctrl._reference_row(j * ts)
        np.testing.assert_allclose(row[3], _feedforward_at(ctrl, j * ts), rtol=1e-12, atol=1e-12)
    assert np.abs(ctrl._plan["u_ff"]).max() > 0.05               # the step does ask for torque


def test_a_time_off_the_cycle_grid_is_evaluated_for_itself(controllers):
    ctrl = controllers["straight"]
    t = 1.2345678
    np.testing.assert_allclose(ctrl._reference_row(t)[3], _feedforward_at(ctrl, t), rtol=1e-12, atol=1e-12)
    j = int(t / SHEET.drive.cycle_time)
    assert not np.allclose(ctrl._reference_row(t)[3], ctrl._plan["u_ff"][j], rtol=0, atol=1e-9)


def test_the_mode_2_allocation_is_the_pseudoinverse_at_the_measured_steering(controllers):
    """Cached by the measured α, the allocation is the pseudoinverse of the stacked input rows there, and
    the chassis row is H_2ᵀB of the chassis column at the α_v the measured α imply."""
    ctrl = controllers["lane_change"]
    rng = np.random.default_rng(2)
    for alpha in rng.uniform(-0.3, 0.3, (6, 2)):
        inertia, inverse = ctrl._chassis_terms(alpha)
        h = ctrl._chassis_column(alpha)
        rows = np.vstack([ctrl._hold_rows, SHEET.drive.i_G * h[5:9][None]])
        np.testing.assert_allclose(inverse, np.linalg.pinv(rows), rtol=1e-12, atol=1e-14)
        assert inertia == pytest.approx(ctrl._chassis_inertia(h), rel=1e-14)
        assert ctrl._chassis_terms(alpha.copy())[1] is inverse                 # the same α: from the cache
        with pytest.raises(ValueError):
            inverse[0, 0] = 1.0                                               # cached arrays are read-only


def test_commands_on_and_off_the_grid_agree_for_the_same_state():
    """Two controllers of one step, fed the same measurements: one at grid times (planned rows), one at
    times a hair off the grid (evaluated per call), command the same torques within the rounding."""
    step = straight_excitation(duration=4.0, seed=3)
    on, off = StepController(step, SHEET), StepController(step, SHEET)
    ts = SHEET.drive.cycle_time
    rng = np.random.default_rng(4)
    for j in range(200):
        m = Measurement(j * ts, rng.normal(size=4), rng.normal(size=4), rng.normal(size=4),
                        rng.normal(scale=0.01, size=2))
        u_on = on.command(j * ts, m)
        u_off = off.command(j * ts * (1 + 1e-15) if j else 0.0, m)
        np.testing.assert_allclose(u_on, u_off, rtol=1e-9, atol=1e-9)


def test_steering_off_the_mode_2_configuration_takes_the_chassis_column_at_the_range_end(controllers):
    """Entering an arc (inner unit at 1.25 rad, outer at 0.50) with the outer unit 0.2 rad ahead, as a
    sticking, slow steering loop leaves it, the measured α imply a virtual angle beyond arctan(l/b); the
    loop keeps commanding, with the column of the range's end."""
    from qomni.ident import kinematics

    ctrl = next(c for name, c in controllers.items() if name.startswith("arc"))
    g = SHEET.geometry
    limit = kinematics.alpha_v_max(g)
    alpha = kinematics.f_icr(np.array([0.746]), g)[0] + np.array([0.0, 0.2])
    assert kinematics.alpha_v_from_alpha(alpha[None], g)[0] > limit
    h = ctrl._chassis_column(alpha)
    at_end = kinematics.H(2, kinematics.f_icr(np.array([limit]), g), g, alpha_v=np.array([limit]))[0][:, 1]
    np.testing.assert_allclose(h, at_end, rtol=1e-12, atol=1e-12)
    inertia, _ = ctrl._chassis_terms(alpha)
    assert np.isfinite(inertia) and inertia > 0


@pytest.mark.parametrize("key, value, message", [
    ("steering_bandwidth", "45", "must be a number"), ("damping", float("nan"), "must be finite"),
    ("chassis_bandwidth", 0.0, "must be > 0"), ("max_dead_time", -0.01, "must be >= 0"),
    ("torque_margin", 1.5, "must be <= 1"), ("min_phase_margin", 95.0, "must be < 90"),
    ("probe", 1, "must be true or false")])
def test_a_recorded_controller_setting_no_controller_can_run_with_is_refused_by_name(key, value, message):
    """Controller settings come back from a run's metadata.json (the twin's campaign repeats them): a value
    that is not a number, not finite or out of its physical range is refused naming the key."""
    from qomni.ident.controller import ControllerSettings

    with pytest.raises(ValueError, match=f"controller.{key} {message}"):
        ControllerSettings(**{key: value})
    assert ControllerSettings(max_dead_time=0.0, steering_bandwidth=20).steering_bandwidth == 20.0
