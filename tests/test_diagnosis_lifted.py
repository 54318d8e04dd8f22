"""What the lifted vehicle's single-axis run tells the diagnosis (docs/diagnosis.md, Which): the drive a
torque-constant error is on, where the wheels' own data cannot rank a weaker and a stronger drive."""
from types import SimpleNamespace as NS

import numpy as np
import pytest

from qomni.diagnosis.hypotheses.base import RuleRows
from qomni.diagnosis.hypotheses.torque_constant_error import (LIFTED_Z, combined_factor, lifted_factor,
                                                              lifted_inertia_ratio, resolve_drive)
from qomni.conventions import WHEELS

B_W, SIGMA = 0.120, 0.0008


def _lifted(faulty: dict[str, float] | None = None) -> dict:
    """Lifted wheels whose B_w reads B_W/f on a drive of torque-constant factor f (one σ of noise apart)."""
    faulty = faulty or {}
    wobble = dict(zip(WHEELS, (-0.5, 0.3, 0.0, 0.6)))
    return {w: {"B_w": (B_W / faulty.get(w, 1.0) + wobble[w] * SIGMA, SIGMA),
                "d_vw": (0.73, 0.002), "d_cw": (3.95, 0.014)} for w in WHEELS}


def _candidate(wheel: str, factor_minus_one: float, significant: bool = True, sigma: float = 0.019):
    """A torque-constant candidate fitted at ``factor_minus_one`` with standard deviation ``sigma``."""
    return NS(hypothesis=NS(name="torque_constant_error", variant=f"drive {wheel}"),
              magnitude=NS(value=factor_minus_one),
              fit=NS(theta=np.array([factor_minus_one]), theta_cov=np.array([[sigma**2]])),
              significant=significant, notes=[])


def _rows(lifted):
    return RuleRows(None, None, None, 1, {}, lifted)


def test_a_faulty_drive_reads_its_wheels_inertia_as_one_over_its_factor_against_the_others_median():
    lifted = _lifted({"rl": 1.13})
    ratio, std = lifted_inertia_ratio(lifted, "rl")
    assert ratio == pytest.approx(1 / 1.13, rel=0.01)
    assert abs(ratio - 1) / std > LIFTED_Z
    for w in ("fl", "fr", "rr"):      # the median keeps the faulty wheel out of the others' reference
        r, s = lifted_inertia_ratio(lifted, w)
        assert abs(r - 1) / s < 1.5


def test_the_lifted_run_names_the_stronger_drive_where_the_wheels_data_name_a_weaker_one_beside_it():
    named, equivalent = _candidate("fl", -0.108), _candidate("rl", 0.109)
    others = [_candidate("fr", 0.01, False), _candidate("rr", -0.01, False)]
    resolve_drive([named, equivalent, *others], _rows(_lifted({"rl": 1.13})))
    assert equivalent.significant and not named.significant
    assert "wheel rl" in equivalent.notes[0] and "drive fl's factor" in named.notes[0]


def test_where_the_lifted_run_cannot_contradict_the_weaker_drive_the_two_measurements_together_do_not_name_it():
    # the fit too uncertain for the lifted run to rule out drive fl by its factor alone (|z| < LIFTED_Z)
    named, equivalent = _candidate("fl", -0.108, sigma=0.05), _candidate("rl", 0.109)
    resolve_drive([named, equivalent], _rows(_lifted({"rl": 1.13})))
    assert equivalent.significant and not named.significant
    assert "wheel rl" in equivalent.notes[0] and "together measure drive fl" in named.notes[0]


@pytest.mark.parametrize("lifted,candidates,why", [
    (None, {"fl": -0.108, "rl": 0.109}, "no single-axis run"),
    (_lifted({"rl": 1.13, "fr": 0.9}), {"rl": 0.118, "fr": -0.095},
     "two wheels off, each as its candidate says: the lifted run singles out none and contradicts neither"),
    (_lifted({"rl": 1.13}), {"rl": 0.112}, "the faulty drive fitted within its σ of the lifted value"),
])
def test_the_lifted_run_keeps_candidates_it_agrees_with(lifted, candidates, why):
    cands = [_candidate(w, v) for w, v in candidates.items()]
    resolve_drive(cands, _rows(lifted))
    assert all(c.significant for c in cands), why


@pytest.mark.parametrize("lifted,wheel,value,why", [
    (_lifted(), "rl", -0.81, "a scrub fitted as a drive at factor 0.19 while its lifted wheel reads as the others"),
    (_lifted(), "fl", -0.108, "no wheel off: no drive 11 % weak"),
    (_lifted({"rl": 0.88}), "rl", 0.109, "the wheel says weaker, the candidate stronger"),
    (_lifted({"rl": 1.13}), "rl", 0.30, "the right drive, three times the lifted run's factor"),
])
def test_a_factor_the_lifted_run_contradicts_is_not_named(lifted, wheel, value, why):
    c = _candidate(wheel, value)
    resolve_drive([c], _rows(lifted))
    assert not c.significant, why
    assert f"drive {wheel}'s factor" in c.notes[0] and "contradicts" in c.notes[0]


def test_a_torque_constant_difference_within_a_motors_thermal_drift_is_not_relevant():
    """Below 1 % (10 K of magnet warming) a drive's torque constant is not reported as a fault, either sign;
    a fitted test names it as too small, not as physically impossible."""
    from qomni.diagnosis.hypotheses.base import plausible
    from qomni.diagnosis.hypotheses.torque_constant_error import RELEVANT_FACTOR, TORQUE_CONSTANT
    h = TORQUE_CONSTANT[0]
    assert RELEVANT_FACTOR == 0.01
    for value in (0.005, -0.005, 0.0099):
        assert h.physical(np.array([value])) and not plausible(h, np.array([value]))
    for value in (0.012, -0.05, 0.15):
        assert plausible(h, np.array([value]))


@pytest.mark.parametrize("lifted,wheel,value,sigma,why", [
    (_lifted(), "rr", -0.103, 0.033, "a load on wheel rr fitted as its drive 10 % weak, too uncertain for "
                                     "the lifted run to contradict (|z| ≈ 2.8)"),
    (_lifted(), "fr", 0.012, 0.019, "a small factor within the lifted run's σ of none"),
    (_lifted(), "fr", 0.0104, 0.0022, "significant on the ground alone, within the lifted run's σ of "
                                      "none, together just under the 1 % of a motor's thermal drift"),
])
def test_a_factor_the_fit_and_the_lifted_run_together_do_not_measure_is_not_named(lifted, wheel, value, sigma,
                                                                                  why):
    c = _candidate(wheel, value, sigma=sigma)
    resolve_drive([c], _rows(lifted))
    assert not c.significant, why
    assert f"together measure drive {wheel}'s factor" in c.notes[0]


def test_the_combined_factor_is_the_inverse_variance_mean_and_keeps_a_drive_both_measure():
    lifted = _lifted({"rl": 0.876})
    value, sigma_lifted = lifted_factor(lifted, "rl")
    c = _candidate("rl", -0.127, sigma=0.0094)
    combined, sigma = combined_factor(c, lifted, "rl")
    w_fit, w_lifted = 1 / 0.0094**2, 1 / sigma_lifted**2
    assert combined == pytest.approx((w_fit * -0.127 + w_lifted * value) / (w_fit + w_lifted))
    assert sigma == pytest.approx((w_fit + w_lifted) ** -0.5) and sigma < min(0.0094, sigma_lifted)
    for level in (1e-2, 1e-2 / 14):
        kept = _candidate("rl", -0.127, sigma=0.0094)
        resolve_drive([kept], RuleRows(None, None, None, 1, {}, lifted, level=level))
        assert kept.significant and not any("together" in n for n in kept.notes)


def test_a_fit_without_a_variance_is_taken_alone_rather_than_dividing_by_zero():
    c = _candidate("rl", -0.12, sigma=0.0)
    assert combined_factor(c, _lifted({"rl": 0.88}), "rl") == (-0.12, 0.0)
    resolve_drive([c], _rows(_lifted({"rl": 0.88})))
    assert c.significant


def _lifted_run(sheet, B_w=0.12, d_vw=0.73, d_cw=3.95, seconds=8.0):
    """Signals of the lifted wheels, each on its own sine, driven by exactly the torque that (19) with the
    chassis at rest asks for: i_G u_i = B_w β̈_i + d_vw β̇_i + d_cw tanh(β̇_i/ε)."""
    from qomni.conventions import EPSILON
    from qomni.ident.recording import Signals

    ts, i_G = sheet.drive.cycle_time, sheet.drive.i_G
    t = np.arange(1, int(seconds / ts) + 1) * ts
    w = np.array([2.1, 2.9, 3.7, 4.3])
    beta = 3.0 * np.sin(w * t[:, None])
    beta_d, beta_dd = 3.0 * w * np.cos(w * t[:, None]), -3.0 * w**2 * np.sin(w * t[:, None])
    tau = B_w * beta_dd + d_vw * beta_d + d_cw * np.tanh(beta_d / EPSILON)
    n = len(t)
    # the torque actual of SYNC j acts over the following cycle: reported at the cycle's mid-point
    u = np.column_stack([np.interp(t + ts / 2, t, tau[:, i]) for i in range(4)]) / i_G
    return Signals(t, np.full(n, "single_axis"), np.zeros(n, int), np.zeros((n, 2)), i_G * beta,
                   i_G * beta_d, u, u)


def test_the_lifted_channel_is_what_the_model_gets_wrong_about_the_lifted_wheels_and_nothing_else():
    from qomni.datasheet import DataSheet
    from qomni.diagnosis.channels import EDGE_ROWS, lifted_channel
    from qomni.diagnosis.hypotheses.base import columns_on
    from qomni.diagnosis.hypotheses.rolling_resistance import ROLLING_RESISTANCE
    from qomni.diagnosis.hypotheses.torque_constant_error import TORQUE_CONSTANT

    sheet = DataSheet.load()
    signals = _lifted_run(sheet)
    p = np.zeros(11)
    p[8], p[9], p[10] = 0.73, 3.95, 0.12           # d_vw, d_cw, B_w (order (18))
    exact = lifted_channel(signals, sheet, NS(p=p))
    assert exact.held_out_only and exact.name == "lifted/beta"
    moving = exact.fitted
    assert moving.mean() > 0.9
    assert np.sqrt(np.mean(exact.residual[moving] ** 2)) < 0.02 * 3.95
    p_high = p.copy()
    p_high[9] += 1.5                              # the ground's share taken into d_cw
    high = lifted_channel(signals, sheet, NS(p=p_high))
    assert np.allclose(high.residual[moving] - exact.residual[moving], -1.5 * high.base[moving, 9])
    assert np.sqrt(np.mean(high.residual[moving] ** 2)) > 1.4
    # no ground under the wheels: no rolling resistance; drive j's torque acts on wheel j's rows alone
    assert columns_on(ROLLING_RESISTANCE, high, None) is None
    rows_per_wheel = len(signals) - 2 * EDGE_ROWS
    for j, h in enumerate(TORQUE_CONSTANT):
        col = columns_on(h, high, None)[:, 0]
        on = np.zeros(len(col), bool)
        on[j * rows_per_wheel:(j + 1) * rows_per_wheel] = True
        assert np.abs(col[on]).max() > 1.0 and not col[~on].any()


def test_the_lifted_wheels_are_simulated_forward_one_wheel_at_a_time():
    from qomni.datasheet import DataSheet
    from qomni.diagnosis.channels import lifted_channel
    from qomni.diagnosis.simulate import simulate_channel

    sheet = DataSheet.load()
    p = np.zeros(11)
    p[8], p[9], p[10] = 0.73, 3.95, 0.12
    ch = lifted_channel(_lifted_run(sheet), sheet, NS(p=p))
    exact = simulate_channel(ch, p)
    # 1 s windows within each wheel's 7.76 s of kept rows: 7 a wheel, none across two wheels' rows
    assert exact["windows"] == 4 * 7
    p_high = p.copy()
    p_high[9] += 1.5
    wrong = simulate_channel(ch, p_high)
    assert exact["rms"] < 0.2 * wrong["rms"] and exact["unit"] == "rad"
