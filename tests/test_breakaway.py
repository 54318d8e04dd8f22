"""The lifted breakaway test (qomni.ident.breakaway) against the emulator's truth, its analysis on
synthetic ramps, and how the gap diagnosis places Stribeck friction by it (docs/diagnosis.md)."""
import json
from types import SimpleNamespace as NS

import numpy as np
import pytest

from qomni.datasheet import DataSheet
from qomni.diagnosis.hypotheses.stribeck import (LIFTED_BREAKAWAY_EXCESS, LIFTED_BREAKAWAY_Z,
                                                 place_by_lifted_breakaway)
from qomni.embedded import embedded_vehicle
from qomni.emulator.description import VehicleDescription
from qomni.emulator.effects import EffectSet
from qomni.ident.breakaway import ONSET, BreakawayPlan, breakaway_torque
from qomni.ident.rundir import RunDirectoryError, read_lifted
from qomni.ident.single_axis import identify_single_axis, plan_single_axis, run_single_axis

SHEET = DataSheet.load()


def _lifted_breakaway(tmp_path, effects: dict, seed: int = 2) -> tuple[float, float]:
    with embedded_vehicle(VehicleDescription.load(), seed=seed, lifted=True,
                          effects=EffectSet.from_dict(effects)) as vehicle:
        run_single_axis(vehicle, SHEET, tmp_path, plan_single_axis())
    identify_single_axis(tmp_path, SHEET)
    recorded = json.loads((tmp_path / "single_axis.json").read_text())     # whose wheels: the campaign checks
    assert recorded["vehicle"] == SHEET.name and recorded["datasheet"]["drive"]["i_G"] == SHEET.drive.i_G
    return read_lifted(tmp_path).breakaway


def _stribeck(ratio, v_s, joints="wheels"):
    return {"stribeck": {"joints": joints, "breakaway_ratio": ratio, "stribeck_velocity": v_s}}


@pytest.mark.parametrize("ratio, v_s", [(1.2, 0.01), (1.2, 0.2), (2.5, 0.05)])
def test_the_lifted_wheels_break_away_at_the_stribeck_ratio_never_read_high(tmp_path, ratio, v_s):
    """Both ends of the realistic range (breakaway 1.2–2.5 × d_c, Stribeck velocity 0.01–0.2 rad/s): the
    excess is read at most a few σ above the truth, at most 30 % below it, and above the placement's bar."""
    excess, std = _lifted_breakaway(tmp_path, _stribeck(ratio, v_s))
    assert excess <= ratio - 1 + 3 * std + 0.01
    assert excess >= 0.7 * (ratio - 1)
    assert excess >= LIFTED_BREAKAWAY_EXCESS and excess / std >= LIFTED_BREAKAWAY_Z


@pytest.mark.parametrize("effects", [{}, _stribeck(2.5, 0.05, joints="steering"), {"backlash": {"gap": 0.02}},
                                     {"actuator_delay": {"delay": 0.02}},
                                     {"torque_constant_error": {"drive": "fl", "factor": 0.87}}],
                         ids=["ideal", "steering_stribeck", "backlash", "actuator_delay", "torque_constant"])
def test_without_a_wheel_joint_peak_the_lifted_wheels_break_away_at_their_coulomb_friction(tmp_path, effects):
    excess, std = _lifted_breakaway(tmp_path, effects)
    assert abs(excess) < 0.03
    assert excess < LIFTED_BREAKAWAY_EXCESS


def _ramp(t_break: float, tau_break: float, rate=5.0, B_w=0.12, play=0.0, dt=0.002, noise=0.25, seed=0):
    """A ramp's rows: the wheel stuck until the torque reaches tau_break at t_break, then turning under
    Coulomb friction (β = rate·s³/(6 B_w)); a gear play turns the encoder by ``play`` in the first rows."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, t_break + 0.2, dt)
    torque = tau_break + rate * (t - t_break) + noise * rng.standard_normal(len(t))
    s = np.maximum(t - t_break, 0.0)
    beta = rate * s**3 / (6 * B_w) + play * np.minimum(t / 0.02, 1.0)
    return t, beta, torque


@pytest.mark.parametrize("play", [0.0, 0.02])
def test_the_breakaway_torque_is_read_where_the_wheel_started_to_turn(play):
    t, beta, torque = _ramp(0.4, 4.0, play=play)
    assert breakaway_torque(t, beta, torque, 0.12) == pytest.approx(4.0, abs=0.05)
    # read at the first row past ONSET, without the turning time, it would be high by rate·s
    s = (6 * 0.12 * ONSET / 5.0) ** (1 / 3)
    assert 5.0 * s > 0.15


def test_a_ramp_whose_wheel_never_turns_has_no_breakaway_torque():
    t = np.arange(0.0, 1.0, 0.002)
    assert breakaway_torque(t, np.zeros_like(t), 2.0 + 5.0 * t, 0.12) is None


def test_the_plan_refuses_ramps_it_cannot_drive():
    with pytest.raises(ValueError, match="directions"):
        BreakawayPlan(directions=(1, 0))
    with pytest.raises(ValueError, match="cap"):
        BreakawayPlan(start=2.0, cap=1.5)
    with pytest.raises(ValueError, match="rate"):
        BreakawayPlan(rate=float("nan"))


def _lifted_json(tmp_path, excess):
    m = {"value": 1.0, "std": 0.01}
    data = {"wheels": {w: {"B_w": m, "d_vw": m, "d_cw": m} for w in ("fl", "rl", "fr", "rr")},
            "pooled": {"B_w": m, "d_vw": m, "d_cw": m}, "breakaway": {"excess": excess}}
    (tmp_path / "single_axis.json").write_text(json.dumps(data))


@pytest.mark.parametrize("excess, why", [({"value": float("nan"), "std": 0.01}, "breakaway.excess"),
                                         ({"value": 0.2, "std": 0.0}, "breakaway.excess"),
                                         ({"value": -1.5, "std": 0.01}, "breakaway.excess must be >= -1"),
                                         ({"std": 0.01}, "breakaway.excess.value/std missing")])
def test_a_bad_breakaway_measurement_is_refused_naming_file_and_key(tmp_path, excess, why):
    _lifted_json(tmp_path, excess)
    with pytest.raises(RunDirectoryError, match=why) as err:
        read_lifted(tmp_path)
    assert "single_axis.json" in str(err.value)


def test_a_run_with_too_few_breakaway_readings_has_no_breakaway_measurement(tmp_path):
    _lifted_json(tmp_path, None)
    assert read_lifted(tmp_path).breakaway is None


def _candidate(variant, significant, p_value=1e-3, shrink=0.3, removed=50.0, theta=(0.5,)):
    from qomni.diagnosis.evaluation import Evaluation
    ev = Evaluation([], 100.0, 100.0 - removed, "steer_left/alpha_l", shrink, (0.0, 0.5))
    return NS(hypothesis=NS(name="stribeck", variant=variant), significant=significant, p_value=p_value,
              physical=True, notes=[], fit=NS(nonlinear=0.05, theta=np.array(theta)), evaluation=ev,
              from_model=ev, presence_p=1e-6)


def _three(wheels=False, steering=True):
    return (_candidate("joints=wheels", wheels), _candidate("joints=steering", steering),
            _candidate("joints=both", True, theta=(0.5, 0.4)))


PEAK, NONE = (0.35, 0.01), (0.004, 0.003)


def test_a_lifted_peak_places_friction_in_the_wheel_joints():
    wheels, steering, both = _three()
    place_by_lifted_breakaway([wheels, steering, both], PEAK, lambda v_s: 0.3)
    assert wheels.significant and not steering.significant and not both.significant
    assert any("excess 0.350" in n for n in wheels.notes)


def test_a_lifted_peak_and_the_lane_changes_steering_level_place_it_in_both_joints():
    wheels, steering, both = _three()
    place_by_lifted_breakaway([wheels, steering, both], PEAK, lambda v_s: 2.5)
    assert both.significant and not wheels.significant and not steering.significant
    assert any("lifted wheels break away" in n for n in both.notes)


@pytest.mark.parametrize("breakaway", [NONE, (0.06, 0.005), (0.2, 0.1)],
                         ids=["none", "below_the_relevant_size", "not_significant"])
def test_without_a_lifted_peak_the_wheel_variant_gives_way_to_the_steering_joints(breakaway):
    wheels, steering, both = _three(wheels=True, steering=False)
    place_by_lifted_breakaway([wheels, steering, both], breakaway, lambda v_s: 2.5)
    assert steering.significant and not wheels.significant and not both.significant
    # a steering variant that does not confirm on held-out data is not named in its place
    wheels, steering, both = _three(wheels=True, steering=False)
    steering.evaluation.shrink_affected = 0.02
    place_by_lifted_breakaway([wheels, steering, both], breakaway)
    assert not (steering.significant or wheels.significant or both.significant)


def test_nothing_is_placed_where_no_stribeck_variant_is_significant():
    wheels, steering, both = _three(wheels=False, steering=False)
    place_by_lifted_breakaway([wheels, steering, both], PEAK, lambda v_s: 2.5)
    assert not (steering.significant or wheels.significant or both.significant)


@pytest.mark.parametrize("theta, sigma, agrees", [(1.9, 0.8, True), (0.7, 0.05, True), (0.2, 0.1, False),
                                                  (4.0, 0.5, False)])
def test_a_ground_fit_agrees_with_the_lifted_excess_within_its_and_the_measurements_sigma(theta, sigma, agrees):
    """The lifted test names a wheel-joint peak the ground's gates missed only where the ground's fitted
    wheel-joint level does not contradict it (two-sided 10⁻³, both σ combined)."""
    from qomni.diagnosis.diagnose import _agrees_with_lifted
    cand = NS(hypothesis=NS(parameters=("breakaway_excess",)),
              fit=NS(theta=np.array([theta]), theta_cov=np.array([[sigma**2]])))
    assert _agrees_with_lifted(cand, 0.7, 0.02) is agrees


HELD_OFF = "the rotation holds the steering left +4.9 LSB, right -4.7 LSB off the mode's angle"


def test_a_steering_held_off_the_rotations_angles_places_the_rest_in_the_steering_joints():
    """A lifted peak, the lane change silent (a peak narrower than its reversals), the rotation holding
    the steering off the mode's angles: friction in both joints; the lane change silent and the steering
    where it should be: the wheel joints."""
    wheels, steering, both = _three()
    place_by_lifted_breakaway([wheels, steering, both], PEAK, lambda v_s: -1.3, HELD_OFF)
    assert both.significant and not wheels.significant and not steering.significant
    assert any(HELD_OFF in n for n in both.notes)
    assert any(HELD_OFF in n for n in wheels.notes if "preferred" in n)    # not the lane change's z
    wheels, steering, both = _three()
    place_by_lifted_breakaway([wheels, steering, both], PEAK, lambda v_s: -1.3, None)
    assert wheels.significant and not both.significant
    assert any("nor a steering held off" in n for n in both.notes)
    # without a lifted peak the steering joints alone are named, held off or not
    wheels, steering, both = _three(wheels=True, steering=False)
    place_by_lifted_breakaway([wheels, steering, both], NONE, lambda v_s: -1.3, HELD_OFF)
    assert steering.significant and not both.significant
