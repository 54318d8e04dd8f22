"""Scoring of the blind suite and the traction-limit rows of the diagnosis, without campaigns."""
import numpy as np
import pytest

from qomni.diagnosis.channels import TRACTION_LIMIT, _segments, traction_limited
from qomni.diagnosis.evaluation import ChannelShrink
from qomni.datasheet import DataSheet
from qomni.blind_suite import Case, CaseResult, excess_shrink, noise_floor, score


def _result(entry, truth, variants, accepted, accepted_variants):
    case = Case(f"{entry}_high_s1", {}, truth, 1, "high", entry, variants)
    return CaseResult(case, accepted=accepted, accepted_variants=accepted_variants)


def test_the_wrong_instance_of_the_right_effect_is_not_top1():
    wrong = _result("stribeck_wheels", ["stribeck"], {"stribeck": "joints=wheels"},
                    ["stribeck"], ["joints=steering"])
    right = _result("stribeck_wheels", ["stribeck"], {"stribeck": "joints=wheels"},
                    ["stribeck"], ["joints=wheels"])
    assert not wrong.top1 and wrong.false_positives == ["stribeck"]
    assert right.top1 and right.false_positives == []
    s = score([wrong, right])
    assert s["top1_accuracy"] == 0.5
    assert s["per_effect"]["stribeck_wheels"] == {"cases": 2, "top1": 1, "false_positives": 1,
                                                  "median_holdout_shrink": None,
                                                  "min_holdout_shrink": None,
                                                  "median_excess_shrink": None,
                                                  "min_excess_shrink": None,
                                                  "median_gap_shrink": None,
                                                  "min_gap_shrink": None,
                                                  "median_beyond_base_fit_shrink": None,
                                                  "min_beyond_base_fit_shrink": None,
                                                  "median_beyond_reference_shrink": None,
                                                  "named_range_positions": [],
                                                  "missed_range_positions": []}


def test_shrink_beyond_the_ideal_floor_counts_only_the_effects_own_residual():
    # Effect residual e (RMS 4) on a floor n (RMS 3): before √(16 + 9) = 5. Removing half of e's RMS
    # leaves √(4 + 9); the raw shrink is 28 %, the shrink beyond the floor 50 %.
    assert excess_shrink(5.0, np.sqrt(13.0), 3.0) == pytest.approx(0.5)
    assert ChannelShrink("rotation/gamma_ch", 5.0, np.sqrt(13.0)).shrink == pytest.approx(0.279, abs=1e-3)
    assert excess_shrink(5.0, 3.0, 3.0) == pytest.approx(1.0)
    assert excess_shrink(5.0, 2.9, 3.0) == pytest.approx(1.0)     # below the floor: all of it removed
    assert excess_shrink(2.9, 2.5, 3.0) is None                   # nothing above the floor to remove
    # the floor is the model as identified's held-out RMS on the ideal cases (the base fit's in results
    # written before that was recorded)
    ideal = [CaseResult(Case(f"ideal_s{s}", {}, [], s), holdout_rms={"rotation/gamma_ch": 0.5 * rms},
                        model_holdout_rms={"rotation/gamma_ch": rms})
             for s, rms in ((1, 3.0), (2, 4.0))]
    assert noise_floor(ideal) == {"rotation/gamma_ch": pytest.approx(np.sqrt(12.5))}
    older = [CaseResult(Case("ideal_s1", {}, [], 1), holdout_rms={"rotation/gamma_ch": 2.0})]
    assert noise_floor(older) == {"rotation/gamma_ch": pytest.approx(2.0)}
    heavy = CaseResult(Case("heavy_steering_units_high_s1", {}, ["heavy_steering_units"], 1, "high",
                            "heavy_steering_units"), accepted=["heavy_steering_units"], accepted_variants=[""],
                       true_shrink={"heavy_steering_units": {"shrink": 0.2, "channel": "rotation/gamma_ch",
                                                             "rms_before": 5.0, "rms_after": 4.0,
                                                             "beyond_base_fit": 0.12,
                                                             "beyond_reference": 0.15}})
    e = score(ideal + [heavy])["per_effect"]["heavy_steering_units"]
    assert e["median_holdout_shrink"] == 0.2
    assert e["median_beyond_reference_shrink"] == 0.15
    assert e["median_beyond_base_fit_shrink"] == e["min_beyond_base_fit_shrink"] == 0.12
    assert e["median_excess_shrink"] == pytest.approx(1 - np.sqrt((16 - 12.5) / (25 - 12.5)))
    assert score([heavy])["per_effect"]["heavy_steering_units"]["median_excess_shrink"] is None



def _rolling_case(before, after, twin, **extra):
    """A rolling-resistance case named rightly, its held-out RMS before/after in its affected channel and
    the twin's RMS there (``extra``: further ``true_shrink`` keys, e.g. ``paired``)."""
    return CaseResult(Case("rolling_resistance_0_s1", {}, ["rolling_resistance"], 1, "drawn", "rolling_resistance"),
                      accepted=["rolling_resistance"], accepted_variants=[""],
                      true_shrink={"rolling_resistance": {"shrink": 1 - after / before, "channel": "rotation/gamma_ch",
                                                          "rms_before": before, "rms_after": after,
                                                          "reference_rms": twin, **extra}})


def test_the_gap_shrink_counts_only_the_residual_beyond_the_cases_own_twin():
    """The gap is what the data leave beyond what the model leaves on the case's own reference run (its
    twin) in the same channel: removing half of the gap's RMS is 50 % there, whatever the twin's floor."""
    # gap RMS 4 on a twin floor of 3: before 5; half the gap's RMS removed leaves √(4 + 9)
    half = _rolling_case(5.0, np.sqrt(13.0), 3.0)
    e = score([half])["per_effect"]["rolling_resistance"]
    assert e["median_gap_shrink"] == pytest.approx(0.5)
    assert e["median_holdout_shrink"] == pytest.approx(1 - np.sqrt(13.0) / 5.0)
    # a channel not above its twin has no gap to shrink; a case without the twin's RMS is not counted
    below = _rolling_case(2.9, 2.5, 3.0)
    older = _rolling_case(5.0, 3.0, None)
    assert score([below, older])["per_effect"]["rolling_resistance"]["median_gap_shrink"] is None
    e = score([half, below, older, _rolling_case(5.0, 3.0, 3.0)])["per_effect"]["rolling_resistance"]
    assert e["min_gap_shrink"] == pytest.approx(0.5) and e["median_gap_shrink"] == pytest.approx(1.0)


def test_a_channel_paired_with_the_twin_is_not_floored_by_the_twin_again():
    """A channel diagnosed beyond the twin's residual at the same instants already holds only the gap: its
    gap shrink is the whole-residual shrink, not the shrink beyond the twin's own RMS a second time."""
    def case(paired):
        return _rolling_case(5.0, np.sqrt(13.0), 3.0, paired=paired)
    assert score([case(False)])["per_effect"]["rolling_resistance"]["median_gap_shrink"] == pytest.approx(0.5)
    e = score([case(True)])["per_effect"]["rolling_resistance"]
    assert e["median_gap_shrink"] == pytest.approx(e["median_holdout_shrink"]) == pytest.approx(1 - np.sqrt(13.0) / 5.0)


def test_traction_limited_rows_are_widened_by_the_margin():
    sheet = DataSheet.load()
    u = np.zeros((500, 4))
    u[200, 2] = -TRACTION_LIMIT * sheet.drive.max_torque
    limited = traction_limited(u, sheet)
    rows = int(round(0.1 / sheet.drive.cycle_time))
    assert limited.sum() == 2 * rows + 1
    assert limited[200 - rows] and limited[200 + rows] and not limited[200 + rows + 1]
    assert not traction_limited(u * 0.99, sheet).any()


@pytest.mark.parametrize("free, expected", [
    ([1, 1, 1], [[1], [1], [1]]),
    ([1, 0, 1, 1, 0], [[1, 0], [0, 0], [0, 1], [0, 1], [0, 0]]),
    ([0, 1, 1], [[0], [1], [1]]),
])
def test_each_stretch_between_limited_rows_gets_its_own_constant(free, expected):
    assert _segments(np.array(free, dtype=bool)).tolist() == expected


def _stribeck(variant, significant, p_value=1e-3, shrink=0.3, v_s=0.02, removed=50.0):
    from types import SimpleNamespace as NS

    from qomni.diagnosis.evaluation import Evaluation
    ev = Evaluation([], 100.0, 100.0 - removed, "steer_left/alpha_l", shrink, (0.0, 0.5))
    return NS(hypothesis=NS(name="stribeck", variant=variant), significant=significant, p_value=p_value,
              physical=True, notes=[], fit=NS(nonlinear=v_s), evaluation=ev, from_model=ev, presence_p=1e-6)


def _decisions(candidate):
    """A candidate's notes but the placement's statement of what it read."""
    return [n for n in candidate.notes if not n.startswith("placement:")]


def test_wheel_friction_is_told_from_steering_friction_by_the_unsteered_steps():
    from qomni.diagnosis.hypotheses.stribeck import WHEEL_FRICTION_Z, tell_friction_joints_apart as _tell_friction_joints_apart
    asked = []

    def z_of(z):
        def unsteered_z(v_s):
            asked.append(v_s)
            return z
        return unsteered_z

    # wheel-joint friction: the steering steps make the steering variant significant, the wheel
    # variant's level in the unsteered steps stands out of the reference's -> wheels, at its own v_s
    wheels, steering = _stribeck("joints=wheels", False, p_value=0.02, v_s=0.05), _stribeck("joints=steering", True)
    _tell_friction_joints_apart([steering, wheels], z_of(WHEEL_FRICTION_Z + 0.4))
    assert wheels.significant and not steering.significant and asked == [0.05]
    assert "z = 2.0" in wheels.notes[0]
    # steering-joint friction: the unsteered steps hold no more of it than the reference run, so the
    # steering variant is named even where the wheel variant removes more held-out residual
    wheels, steering = _stribeck("joints=wheels", True, removed=60.0), _stribeck("joints=steering", True)
    _tell_friction_joints_apart([steering, wheels], z_of(WHEEL_FRICTION_Z - 0.1))
    assert steering.significant and not wheels.significant and not _decisions(steering)
    assert "z = 1.5" in wheels.notes[0]
    # no column in the unsteered steps (e.g. a run without them): nothing to decide on
    wheels, steering = _stribeck("joints=wheels", True), _stribeck("joints=steering", True)
    _tell_friction_joints_apart([steering, wheels], z_of(None))
    assert steering.significant and wheels.significant
    # the wheel variant must still remove held-out residual itself
    wheels, steering = _stribeck("joints=wheels", False, shrink=0.05), _stribeck("joints=steering", True)
    _tell_friction_joints_apart([steering, wheels], z_of(3.0))
    assert not wheels.significant and not steering.significant
    # ... and must not add held-out residual elsewhere
    wheels, steering = _stribeck("joints=wheels", False, removed=-20.0), _stribeck("joints=steering", True)
    _tell_friction_joints_apart([steering, wheels], z_of(3.0))
    assert not wheels.significant
    # nothing is asked when no Stribeck variant is significant
    asked.clear()
    _tell_friction_joints_apart([_stribeck("joints=steering", False), _stribeck("joints=wheels", False)],
                                z_of(3.0))
    assert asked == []


def test_the_unsteered_bar_is_half_the_z_the_wheel_level_predicts_where_that_is_below_5_percent():
    """The unsteered steps' z is compared with the z the wheel variant's own level would give there: at
    or above half of it (closer to the wheel joints' prediction than to none) the friction is placed in
    the wheel joints even below the one-sided 5 % bar; a strong prediction keeps the 5 % bar."""
    from types import SimpleNamespace as NS

    from qomni.diagnosis.hypotheses.stribeck import tell_friction_joints_apart as _tell_friction_joints_apart

    def pair(level, wheels_significant=False):
        wheels = _stribeck("joints=wheels", wheels_significant, v_s=0.05)
        steering = _stribeck("joints=steering", True)
        wheels.fit = NS(nonlinear=0.05, theta=np.array([level]), theta0=np.array([0.0]))
        return wheels, steering

    wheels, steering = pair(0.2)                    # predicts z = 0.2/0.1 = 2.0 there: bar 1.0
    _tell_friction_joints_apart([steering, wheels], lambda v_s: 1.3, None, lambda v_s: 0.1)
    assert wheels.significant and not steering.significant
    wheels, steering = pair(0.2, True)              # the unsteered level nearer none than the prediction
    _tell_friction_joints_apart([steering, wheels], lambda v_s: 0.9, None, lambda v_s: 0.1)
    assert steering.significant and not wheels.significant and "z = 0.9 < 1)" in wheels.notes[0]
    wheels, steering = pair(1.0, True)              # predicts z = 10: the 5 % bar holds
    _tell_friction_joints_apart([steering, wheels], lambda v_s: 1.3, None, lambda v_s: 0.1)
    assert steering.significant and not wheels.significant and "< 1.645)" in wheels.notes[0]


def test_wheel_variant_alone_significant_is_placed_in_the_steering_joints_when_unsteered_steps_lack_it():
    """Only the wheel variant passes the steering steps' test, but the unsteered steps hold no more of it
    than the reference run: the friction is established, not in the wheel joints -> steering variant,
    with the wheel variant's p, if that one confirms on held-out data; with z above the bar the wheel
    variant stays."""
    from qomni.diagnosis.hypotheses.stribeck import WHEEL_FRICTION_Z, tell_friction_joints_apart as _tell_friction_joints_apart
    wheels = _stribeck("joints=wheels", True, p_value=5.6e-3)
    steering = _stribeck("joints=steering", False, p_value=1.2e-2)
    _tell_friction_joints_apart([steering, wheels], lambda v_s: 0.0)
    assert steering.significant and not wheels.significant
    assert "p = 5.6e-03" in steering.notes[0]
    # the steering variant must itself confirm on held-out data, else the wheel variant stays
    wheels = _stribeck("joints=wheels", True)
    steering = _stribeck("joints=steering", False, removed=-3.3)
    _tell_friction_joints_apart([steering, wheels], lambda v_s: 0.0)
    assert wheels.significant and not steering.significant and not _decisions(wheels)
    wheels, steering = _stribeck("joints=wheels", True), _stribeck("joints=steering", False)
    _tell_friction_joints_apart([steering, wheels], lambda v_s: WHEEL_FRICTION_Z + 0.4)
    assert wheels.significant and not steering.significant


def _both(theta, std, theta0=(0.0, 0.0), physical=True):
    from types import SimpleNamespace as NS

    from qomni.diagnosis.evaluation import Evaluation
    ev = Evaluation([], 100.0, 50.0, "steer_left/alpha_l", 0.3, (0.0, 0.5))
    cov = np.diag(np.square(std))
    return NS(hypothesis=NS(name="stribeck", variant="joints=both"), significant=True, p_value=1e-3,
              physical=physical, notes=[], evaluation=ev, from_model=ev, presence_p=1e-6,
              fit=NS(nonlinear=0.05, theta=np.array(theta), theta_cov=cov, theta0=np.array(theta0)))


def test_friction_in_both_joints_is_named_where_the_steering_steps_need_more_than_the_wheels_give():
    """The unsteered steps place friction in the wheel joints; the both-joints fit, whose wheel coefficient
    they hold, still needs a steering coefficient beyond the reference run's -> both joints, in place of
    the variant the placement chose. Without that excess, or without the wheel joints placed, the
    single-joint verdict stays; the both-joints variant is never named by its own test."""
    from qomni.diagnosis.hypotheses.stribeck import STEERING_BEYOND_WHEELS_Z, WHEEL_FRICTION_Z, \
        tell_friction_joints_apart
    z_w = WHEEL_FRICTION_Z + 1.0
    # steering coefficient 1.2 beyond a reference level of 0.4, σ 0.2: z = 4
    wheels, steering, both = (_stribeck("joints=wheels", True), _stribeck("joints=steering", True),
                              _both([1.0, 1.2], [0.3, 0.2], theta0=[0.1, 0.4]))
    tell_friction_joints_apart([wheels, steering, both], lambda v_s: z_w)
    assert both.significant and not wheels.significant and not steering.significant
    assert "z = 4.0" in both.notes[0] and "1.2" in both.notes[0]
    # the same fit, but the steering coefficient only just at the reference's level: wheel joints alone
    wheels, steering, both = (_stribeck("joints=wheels", True), _stribeck("joints=steering", True),
                              _both([1.0, 0.4 + 0.2 * (STEERING_BEYOND_WHEELS_Z - 0.1)], [0.3, 0.2],
                                    theta0=[0.1, 0.4]))
    tell_friction_joints_apart([wheels, steering, both], lambda v_s: z_w)
    assert wheels.significant and not steering.significant and not both.significant
    assert "not named" in both.notes[0]
    # the unsteered steps do not place friction in the wheel joints: the steering joints, not both
    wheels, steering, both = (_stribeck("joints=wheels", True), _stribeck("joints=steering", True),
                              _both([1.0, 1.2], [0.3, 0.2]))
    tell_friction_joints_apart([wheels, steering, both], lambda v_s: WHEEL_FRICTION_Z - 0.5)
    assert steering.significant and not wheels.significant and not both.significant
    # a both-joints fit that passed its own test but no single variant did: nothing named
    wheels, steering, both = (_stribeck("joints=wheels", False), _stribeck("joints=steering", False),
                              _both([1.0, 1.2], [0.3, 0.2]))
    tell_friction_joints_apart([wheels, steering, both], lambda v_s: z_w)
    assert not (wheels.significant or steering.significant or both.significant)
    # physically impossible (a negative coefficient): not named
    wheels, steering, both = (_stribeck("joints=wheels", True), _stribeck("joints=steering", True),
                              _both([-0.2, 1.2], [0.3, 0.2], physical=False))
    tell_friction_joints_apart([wheels, steering, both], lambda v_s: z_w)
    assert wheels.significant and not both.significant


def test_the_lane_change_places_friction_in_the_steering_joints_beside_the_wheels():
    """Where a lane change was recorded, its steering channel (steering turning while the wheels roll at
    speed) decides whether the steering joints have friction beside the wheel joints, not the steering
    steps' both-joints fit: there a wheel-joint peak shows stronger than its column and the fit hands the
    excess to the steering joints. The lane change is asked once, at the Stribeck velocity the steering
    variant's fit profiled on the steering steps, so its bar is a one-sided 5 %."""
    from scipy import stats

    from qomni.diagnosis.hypotheses.stribeck import LANE_CHANGE_STEERING_Z, STRIBECK_VELOCITIES, \
        WHEEL_FRICTION_Z, tell_friction_joints_apart
    assert LANE_CHANGE_STEERING_Z == pytest.approx(stats.norm.isf(0.05))
    z_w = WHEEL_FRICTION_Z + 1.0
    asked = []

    def lane_change(peak, at=STRIBECK_VELOCITIES[-1]):
        """z = ``peak`` at the Stribeck velocity ``at``, 0 elsewhere on the grid."""
        def steered_z(v_s):
            asked.append(v_s)
            return None if peak is None else (peak if v_s == at else 0.0)
        return steered_z

    # the steering steps ask for steering-joint friction (z = 4), the lane change shows none: wheels
    wheels, steering, both = (_stribeck("joints=wheels", True), _stribeck("joints=steering", True),
                              _both([1.0, 1.2], [0.3, 0.2], theta0=[0.1, 0.4]))
    tell_friction_joints_apart([wheels, steering, both], lambda v_s: z_w, lane_change(0.3))
    assert wheels.significant and not steering.significant and not both.significant
    assert "the lane change" in both.notes[0] and "not named" in both.notes[0]
    assert set(asked) == {steering.fit.nonlinear}            # once, at the steering variant's velocity
    # just below the bar: still the wheels
    wheels, steering, both = (_stribeck("joints=wheels", True), _stribeck("joints=steering", True, v_s=0.1),
                              _both([1.0, 1.2], [0.3, 0.2], theta0=[0.1, 0.4]))
    tell_friction_joints_apart([wheels, steering, both], lambda v_s: z_w,
                               lane_change(LANE_CHANGE_STEERING_Z - 0.1, at=0.1))
    assert wheels.significant and not both.significant
    # the lane change shows it at the steering variant's velocity although the steering steps'
    # coefficient is at the reference's level: both
    wheels, steering, both = (_stribeck("joints=wheels", True),
                              _stribeck("joints=steering", True, v_s=STRIBECK_VELOCITIES[1]),
                              _both([1.0, 0.45], [0.3, 0.2], theta0=[0.1, 0.4]))
    tell_friction_joints_apart([wheels, steering, both], lambda v_s: z_w,
                               lane_change(LANE_CHANGE_STEERING_Z + 0.5, at=STRIBECK_VELOCITIES[1]))
    assert both.significant and not wheels.significant and not steering.significant
    assert "the lane change" in both.notes[0]
    # ... but not at another velocity of the grid: that one is not asked
    wheels, steering, both = (_stribeck("joints=wheels", True),
                              _stribeck("joints=steering", True, v_s=STRIBECK_VELOCITIES[3]),
                              _both([1.0, 0.45], [0.3, 0.2], theta0=[0.1, 0.4]))
    tell_friction_joints_apart([wheels, steering, both], lambda v_s: z_w,
                               lane_change(LANE_CHANGE_STEERING_Z + 0.5, at=STRIBECK_VELOCITIES[1]))
    assert wheels.significant and not both.significant
    # the lane change cannot move the wheels into the verdict: without the unsteered steps' z, steering
    wheels, steering, both = (_stribeck("joints=wheels", True), _stribeck("joints=steering", True),
                              _both([1.0, 1.2], [0.3, 0.2]))
    tell_friction_joints_apart([wheels, steering, both], lambda v_s: WHEEL_FRICTION_Z - 0.5, lane_change(5.0))
    assert steering.significant and not wheels.significant and not both.significant
    # no level to fit in the lane change at any grid velocity: the both-joints fit decides
    wheels, steering, both = (_stribeck("joints=wheels", True), _stribeck("joints=steering", True),
                              _both([1.0, 1.2], [0.3, 0.2], theta0=[0.1, 0.4]))
    tell_friction_joints_apart([wheels, steering, both], lambda v_s: z_w, lane_change(None))
    assert both.significant and "the steering steps" in both.notes[0]


def test_a_further_effect_is_tested_at_the_first_rounds_level_shared_over_the_hypotheses_left():
    from qomni.diagnosis.fit import ALPHA, alpha_more
    assert alpha_more(16) == pytest.approx(ALPHA / 16)
    assert alpha_more(1) == ALPHA and alpha_more(0) == ALPHA


def test_a_steering_held_off_in_the_rotation_places_friction_in_the_steering_joints_beside_the_wheels():
    """Without the lifted test: the unsteered steps place friction in the wheel joints, the lane change
    shows none in the steering joints (a peak narrower than its reversals), but the rotation holds the
    steering off the mode's angle -> both joints, the note saying what the rotation read; without that
    reading the wheel joints stay."""
    from qomni.diagnosis.hypotheses.stribeck import WHEEL_FRICTION_Z, tell_friction_joints_apart
    z_w = WHEEL_FRICTION_Z + 1.0
    held_off = "the rotation holds the steering right -9.4 LSB off the mode's angle (the reference run +1.4)"
    for reading, named in ((held_off, "joints=both"), (None, "joints=wheels")):
        wheels, steering, both = (_stribeck("joints=wheels", True), _stribeck("joints=steering", True),
                                  _both([1.0, 0.45], [0.3, 0.2], theta0=[0.1, 0.4]))
        tell_friction_joints_apart([wheels, steering, both], lambda v_s: z_w, lambda v_s: -1.3, None, reading)
        assert [c.hypothesis.variant for c in (wheels, steering, both) if c.significant] == [named]
        assert (reading is not None) == any(held_off in n for n in both.notes)
