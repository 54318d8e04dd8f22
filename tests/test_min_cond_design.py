"""The min_cond excitation design (ident/min_cond_design.py) and the planned campaign's
cond(Θ̂₁ᵀΘ̂₁) (ident/planned_regressor.py): docs/identification.md, "Optimised excitation"."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from qomni.datasheet import DataSheet
from qomni.ident import filtering
from qomni.ident import min_cond_design as design
from qomni.ident.campaign import IDENTIFICATION_STEPS, CampaignSettings, plan
from qomni.ident.planned_regressor import planned_condition
from qomni.ident.regressor import VELOCITY_THRESHOLD

HEAVY = "emulator/data/heavy_platform.toml"
MIN_COND = CampaignSettings(excitation="min_cond")
LIMITS = {"alpha_l": ("alpha_max", "alpha_dot_max", "alpha_ddot_max"),
          "alpha_r": ("alpha_max", "alpha_dot_max", "alpha_ddot_max"),
          "x_ch": ("x_max", "x_dot_max", "x_ddot_max"),
          "gamma_ch": ("gamma_max", "gamma_dot_max", "gamma_ddot_max")}


def test_the_two_level_profile_covers_no_way_and_leaves_rest_and_reversals_gently():
    dt, near, gentle = 1e-4, 0.2, 2.4
    t = np.arange(0.0, 6.0, dt)
    v = design.two_level_velocity(t, 6.0, 0.25, 2.5, 8.0, near=near, gentle=gentle)
    assert abs(v.sum() * dt) < 1e-3                                  # rest to rest: zero displacement
    assert v.max() == pytest.approx(0.25) and v.min() == pytest.approx(-2.5)
    slow = np.isclose(v, 0.25)
    assert 0.75 < slow.mean() < 0.9                                  # most of the period on the slow level
    # from every rest or sign change, |q̇| needs near/gentle s to reach ``near``
    still = np.nonzero((np.abs(v) < 1e-9) | (np.sign(v) != np.sign(np.roll(v, 1))))[0]
    fast_enough = np.nonzero(np.abs(v) >= near)[0]
    j = np.clip(np.searchsorted(still, fast_enough), 1, still.size - 1)
    gap = np.minimum(np.abs(fast_enough - still[j]), np.abs(fast_enough - still[j - 1])) * dt
    assert gap.min() >= near / gentle - 2 * dt


@pytest.mark.parametrize("bursts", [1, 2, 3])
def test_the_burst_profile_covers_no_way_holds_the_slow_level_between_bursts_and_leaves_reversals_gently(bursts):
    dt, slow, peak, accel, near, gentle = 1e-4, 0.0625, 0.8, 0.8, 0.05, 0.6
    t = np.arange(0.0, 14.0, dt)
    v = design.burst_velocity(t, 14.0, slow, peak, accel, near=near, gentle=gentle, bursts=bursts)
    assert abs(v.sum() * dt) < 1e-3                                  # rest to rest: zero displacement
    tol = 2 * accel * dt                                             # a peak falls between samples
    assert v.max() == pytest.approx(peak, abs=tol) and v.min() == pytest.approx(-peak, abs=tol)
    on_slow = np.isclose(np.abs(v), slow)
    burst_time = 2 * bursts * 2 * (peak - slow) / accel              # bursts each way, up and back
    rest_and_reversals = 2 * 0.1 + 6 * slow / gentle                  # pauses; from and to rest, 2 reversals
    assert on_slow.mean() >= 1 - (burst_time + rest_and_reversals) / 14.0   # the slow level holds the rest
    # one burst up and back per excursion: the peaks are reached 2 × bursts times (bursts each way)
    at_peak = np.isclose(np.abs(v), peak, atol=tol)
    peaks = np.nonzero(at_peak & ~np.roll(at_peak, 1))[0]
    assert peaks.size == 2 * bursts
    qdd = np.gradient(v, dt)
    assert np.abs(qdd[np.abs(v) < near - tol]).max() <= gentle * 1.01   # gentle through |q̇| < near
    assert np.abs(qdd).max() <= accel * 1.01


def test_a_burst_profile_the_period_cannot_hold_is_refused():
    with pytest.raises(ValueError, match="cannot hold"):
        design.burst_velocity(np.zeros(3), 3.0, 0.0625, 0.8, 0.8, near=0.05, gentle=0.6, bursts=3)
    with pytest.raises(ValueError, match="bursts"):
        design.burst_velocity(np.zeros(3), 14.0, 0.0625, 0.8, 0.8, near=0.05, gentle=0.6, bursts=0)


def test_the_chassis_steps_spend_the_slack_below_the_target_on_acceleration():
    """The capped chassis designs hold more acceleration than the uncapped (lowest-cond) ones within the
    same limits, and the planned stack stays within the target less the margin."""
    from qomni.ident.campaign import PLANNED_COND_MARGIN

    sheet = DataSheet.load()
    steps = {s.name: s for s in plan(sheet, MIN_COND)}
    for name, coordinate, q_max, qd_max, qdd_max in (("straight", "x_ch", "x_max", "x_dot_max", "x_ddot_max"),
                                                     ("rotation", "gamma_ch", "gamma_max", "gamma_dot_max",
                                                      "gamma_ddot_max")):
        limits = [getattr(MIN_COND, k) for k in (q_max, qd_max, qdd_max)]
        uncapped = design.design_min_cond_trajectory(
            duration=steps[name].trajectories[coordinate].duration, q_min=-limits[0], q_max=limits[0],
            qd_max=limits[1], qdd_max=limits[2], threshold=VELOCITY_THRESHOLD[coordinate])
        rms = [float(np.sqrt(np.mean(tr.evaluate(np.arange(0.0, tr.duration, 2e-3))[2] ** 2)))
               for tr in (steps[name].trajectories[coordinate], uncapped)]
        assert rms[0] > 1.2 * rms[1], name
    assert planned_condition(sheet, MIN_COND) <= (1 - PLANNED_COND_MARGIN) * MIN_COND.cond_target


def test_the_chassis_cap_is_the_largest_whose_planned_stack_stays_within_the_bound(monkeypatch):
    """The cap search, on a stack cond that jumps above the bound past a cap of 4.7."""
    from qomni.ident import campaign, planned_regressor

    tried = []
    monkeypatch.setattr(planned_regressor, "steps_condition",
                        lambda steps, sheet: steps[-1] + (1.0 if steps[-1] > 4.7 else 0.0))
    monkeypatch.setattr(campaign, "trajectory_pair_condition", lambda *a: 4.31)

    def chassis(cap):
        tried.append(cap)
        return [cap]

    steering = plan(DataSheet.load(), CampaignSettings())[:1]
    chosen = campaign._capped_chassis(steering, chassis, DataSheet.load(), 5.0)
    assert chosen == [pytest.approx(4.7, abs=campaign.CAP_RESOLUTION)] and chosen[0] <= 4.7
    assert tried[:2] == [4.31, 5.0]
    # a target below the steering pair's cond: the chassis at the steering pair's cap
    assert campaign._capped_chassis(steering, chassis, DataSheet.load(), 4.0) == [4.31]


def test_a_cond_target_of_one_or_less_is_refused_by_name():
    with pytest.raises(ValueError, match="settings.cond_target"):
        CampaignSettings(cond_target=1.0)


def test_a_period_too_short_for_the_ramps_is_refused():
    with pytest.raises(ValueError, match="base period"):
        design.two_level_velocity(np.zeros(3), 0.5, 0.25, 2.5, 8.0, near=0.2, gentle=2.4)


@pytest.mark.parametrize("vehicle", [None, HEAVY])
def test_the_full_campaign_is_planned_with_cond_below_five_and_a_third_of_the_richness_design(vehicle):
    sheet = DataSheet.load(vehicle)
    optimised = planned_condition(sheet, MIN_COND)
    richness = planned_condition(sheet, CampaignSettings())
    assert optimised <= 5.0 and optimised < richness / 3


def test_each_optimised_step_stays_in_its_limits_rests_at_both_ends_and_keeps_no_row_near_a_reversal():
    settings = MIN_COND
    reach = design.REVERSAL_REACH / filtering.OMEGA_G
    for step in plan(DataSheet.load(), settings):
        if step.name not in IDENTIFICATION_STEPS:
            continue
        ((coordinate, trajectory),) = step.trajectories.items()
        q_max, qd_max, qdd_max = (getattr(settings, name) for name in LIMITS[coordinate])
        t = np.arange(0.0, trajectory.duration, 1e-3)
        q, qd, qdd = trajectory.evaluate(t)
        assert np.abs(q).max() <= q_max and np.abs(qd).max() <= qd_max and np.abs(qdd).max() <= qdd_max
        ends = trajectory.evaluate(np.array([0.0, trajectory.duration]))
        assert np.allclose([ends[0], ends[1], ends[2]], 0.0, atol=1e-9)
        threshold = VELOCITY_THRESHOLD[coordinate]
        cond, kept = design.pair_condition(qd, qdd, threshold)
        assert cond < settings.cond_target and kept > 0.65, step.name
        near = design.near_reversal(qd, threshold, int(reach / 1e-3)) & (np.abs(qd) >= threshold)
        assert near.mean() < 0.02, step.name


def test_the_shipped_designs_are_the_campaigns_and_those_it_drives_are_what_the_design_gives_afresh(monkeypatch):
    shipped = json.loads(design.SHIPPED_DESIGNS.read_text())
    looked_up = []

    class Logged(dict):
        def get(self, key, default=None):
            looked_up.append(key)
            return super().get(key, default)

    monkeypatch.setattr(design, "_shipped", lambda: Logged(shipped))
    steps = {s.name: s for s in plan(DataSheet.load(), MIN_COND)}
    # the steering design (both sides share it), and a straight and a rotation for each chassis cap the
    # search tries: every one the planning looks up is shipped, and nothing else is
    assert set(looked_up) == set(shipped) and len(shipped) % 2 == 1
    for name in IDENTIFICATION_STEPS[1:]:
        ((_, trajectory),) = steps[name].trajectories.items()
        (key,) = [k for k, d in shipped.items() if len(d["a"]) == trajectory.a.size
                  and np.allclose(d["a"], trajectory.a) and np.allclose(d["b"], trajectory.b)]
        inputs = json.loads(key)
        inputs.pop("version")
        inputs.update({k: int(inputs[k]) for k in ("n_harmonics", "evaluations")})
        a, b, periods, omega = design._design.__wrapped__(**inputs)
        old, new = shipped[key], {"a": a, "b": b, "periods": periods, "omega_f": omega}
        assert new["periods"] == old["periods"] and new["omega_f"] == pytest.approx(old["omega_f"]), name
        measures = []
        for d in (old, new):
            tr = design.FourierTrajectory.from_start(d["omega_f"], np.array(d["a"]), np.array(d["b"]),
                                                    periods=d["periods"])
            _, qd, qdd = tr.evaluate(np.arange(0.0, tr.duration, 2e-3))
            measures.append((design.pair_condition(qd, qdd, inputs["threshold"])[0], np.sqrt(np.mean(qdd ** 2))))
        assert measures[1] == pytest.approx(measures[0], rel=0.03), name
    args = dict(duration=12.0, q_min=-0.6, q_max=0.6, qd_max=2.5, qdd_max=10.0, q_start=0.0, threshold=0.2,
                n_harmonics=8, slow_factor=1.25, lost_weight=1.0, evaluations=800, margin=0.995)
    assert design._design.__wrapped__(**args) == design._design.__wrapped__(**args)


def test_a_malformed_shipped_design_is_refused_naming_the_file_and_the_design(tmp_path, monkeypatch):
    bad = tmp_path / "designs.json"
    bad.write_text(json.dumps({"steer": {"a": [0.0, math.nan, 0.0, 0.0], "b": [0.0] * 4, "periods": 2,
                                         "omega_f": 1.0}}))
    monkeypatch.setattr(design, "SHIPPED_DESIGNS", bad)
    design._shipped.cache_clear()
    try:
        with pytest.raises(ValueError, match=r"designs\.json: design steer"):
            design._shipped()
        bad.write_text("{not json")
        design._shipped.cache_clear()
        with pytest.raises(ValueError, match=r"designs\.json: not readable JSON"):
            design._shipped()
    finally:
        design._shipped.cache_clear()


def test_an_unknown_excitation_criterion_is_refused_by_name():
    with pytest.raises(ValueError, match="settings.excitation"):
        CampaignSettings(excitation="d_optimal")
    assert CampaignSettings.quick().excitation == "richness" and CampaignSettings().excitation == "richness"


def test_a_campaign_states_its_planned_cond_before_the_vehicle_moves(tmp_path):
    from qomni.ident.campaign import Campaign

    sheet = DataSheet.load()
    campaign = Campaign(sheet, tmp_path / "run", MIN_COND)
    assert campaign.planned_condition == pytest.approx(planned_condition(sheet, MIN_COND))
    assert campaign.planned_condition <= 5
    assert campaign._metadata()["planned_condition_number"] == campaign.planned_condition
