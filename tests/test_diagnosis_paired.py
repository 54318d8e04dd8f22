"""A paired reference run (the data's campaign on the model's twin): which runs pair, and how a torque
channel's residual becomes the data's beyond the twin's at the same sample (diagnosis/paired.py)."""
from types import SimpleNamespace

import numpy as np

from qomni.diagnosis.channels import ChannelData
from qomni.diagnosis.paired import pair_channels, paired_runs, pairing_shift

TS = 0.002
SETTINGS = {"seed": 7, "steer_duration": 12.0, "lane_changes": 2, "arc_duration": 10.0}
SEGMENTS = [{"name": "rest", "k": 1, "t_start": 0.0, "t_end": 0.502},
            {"name": "steer_left", "k": 1, "t_start": 0.502, "t_end": 12.504}]


def _channel(name, kind, time, y, model=None, fitted=None):
    n = len(time)
    context = SimpleNamespace(st=SimpleNamespace(time=np.asarray(time)), keep=np.ones(n, bool))
    return ChannelData(name, kind, "N", 0, np.asarray(y, float), np.zeros((n, 10)),
                       np.zeros(n) if model is None else np.asarray(model, float), np.zeros(n), np.zeros(n),
                       np.ones(n, bool) if fitted is None else np.asarray(fitted), context)


def test_runs_pair_only_where_the_reference_ran_the_datas_campaign():
    data = {"settings": SETTINGS, "segments": SEGMENTS}
    assert paired_runs(data, {"settings": dict(SETTINGS), "segments": [dict(s) for s in SEGMENTS]}, TS)
    # a boundary written with round-off within half a cycle still pairs
    shifted = [dict(s) for s in SEGMENTS]
    shifted[1]["t_end"] += 0.4 * TS
    assert paired_runs(data, {"settings": SETTINGS, "segments": shifted}, TS)
    # another seed, a step a cycle longer, another step order, no segments: not the same campaign
    assert not paired_runs(data, {"settings": {**SETTINGS, "seed": 8}, "segments": SEGMENTS}, TS)
    longer = [dict(s) for s in SEGMENTS]
    longer[1]["t_end"] += TS
    assert not paired_runs(data, {"settings": SETTINGS, "segments": longer}, TS)
    assert not paired_runs(data, {"settings": SETTINGS, "segments": SEGMENTS[::-1]}, TS)
    assert not paired_runs(data, {"settings": SETTINGS}, TS)
    assert not paired_runs({"segments": SEGMENTS}, {"segments": SEGMENTS}, TS)


def test_a_run_cut_short_pairs_with_its_twin_over_the_steps_it_completed():
    """A stopped run records only the segments it completed: the campaign's first ones. Its twin drove the
    whole campaign; they pair over the data's steps. A reference cut short does not pair with longer data,
    nor does data whose steps are not the reference's first ones."""
    data = {"settings": SETTINGS, "segments": SEGMENTS[:-1], "status": "aborted: KeyboardInterrupt: "}
    twin = {"settings": SETTINGS, "segments": SEGMENTS, "status": "complete"}
    assert pairing_shift(data, twin, TS) == 0
    assert not paired_runs({**twin, "segments": SEGMENTS}, {**data}, TS)
    assert not paired_runs({**data, "segments": SEGMENTS[1:]}, twin, TS)


def test_a_run_recorded_before_a_setting_existed_pairs_with_a_twin_that_records_it():
    """The twin records every setting; the data's run only those that existed then, and a setting added
    later defaults to what runs drove before it. A setting the campaign does not know never pairs, nor
    does a different planned cond (the design procedure changed for the same settings)."""
    from qomni.ident.campaign import CampaignSettings, recorded_settings

    twin = {"settings": vars(recorded_settings(SETTINGS)), "segments": SEGMENTS}
    data = {"settings": SETTINGS, "segments": SEGMENTS}
    assert twin["settings"] != SETTINGS and paired_runs(data, twin, TS)
    assert vars(recorded_settings({})) != vars(CampaignSettings())          # an old run: one lane change
    assert not paired_runs({"settings": {**SETTINGS, "retired": 1}, "segments": SEGMENTS}, twin, TS)
    assert paired_runs({**data, "planned_condition_number": 18.3}, {**twin, "planned_condition_number": 18.3}, TS)
    assert not paired_runs({**data, "planned_condition_number": 4.48}, {**twin, "planned_condition_number": 4.65},
                           TS)


def test_a_paired_torque_channel_keeps_what_the_twin_does_not_show_at_the_same_sample():
    rng = np.random.default_rng(3)
    t = 1.0 + TS * np.arange(400)
    structure = 12.0 * np.sin(2 * np.pi * 1.3 * t)          # the model's own residual, in both runs
    effect = 2.0 * np.cos(2 * np.pi * 0.7 * t)              # only in the data
    model = 5.0 * np.ones_like(t)
    data_y = model + structure + effect + 0.1 * rng.standard_normal(len(t))
    # the twin's rows: one sample missing, the rest in another order, times with round-off
    keep = np.ones(len(t), bool)
    keep[17] = False
    order = rng.permutation(np.flatnonzero(keep))
    twin_y = model + structure + 0.1 * rng.standard_normal(len(t))
    data = [_channel("lane_change/x_ch", "torque", t, data_y, model),
            _channel("steer_left/kinematic_fl", "kinematic", t, np.ones_like(t))]
    ref = [_channel("lane_change/x_ch", "torque", t[order] + 1e-9, twin_y[order], model[order]),
           _channel("steer_left/kinematic_fl", "kinematic", t, np.zeros_like(t))]
    d, r = pair_channels(data, ref, TS)

    gap = d[0]
    assert gap.paired is not None and not gap.fitted[17] and gap.fitted.sum() == len(t) - 1
    rows = gap.fitted
    assert np.sqrt(np.mean((gap.residual[rows] - effect[rows]) ** 2)) < 0.2      # the structure is gone
    assert np.sqrt(np.mean(data[0].residual ** 2)) > 8.0                         # it was there before
    np.testing.assert_allclose(r[0].residual, 0.0, atol=1e-12)                   # the twin holds none of it
    # kinematic channels stay as they are, in both runs
    assert d[1] is data[1] and r[1] is ref[1] and d[1].paired is None


def test_repeats_of_the_reference_pair_the_data_with_their_mean_residual():
    """Further runs of the twin's campaign on other noise draws: the data are paired with the mean of the
    runs' residuals, whose noise shrinks as 1/√K while the structure they share stays whole; a sample
    missing from any run is not fitted, and a channel one run lacks stays unpaired."""
    rng = np.random.default_rng(5)
    t = 1.0 + TS * np.arange(4000)
    structure = 12.0 * np.sin(2 * np.pi * 1.3 * t)
    effect = 2.0 * np.cos(2 * np.pi * 0.7 * t)
    model = np.zeros_like(t)
    noise = 1.0
    data_y = structure + effect + noise * rng.standard_normal(len(t))
    data = [_channel("straight/x_ch", "torque", t, data_y, model),
            _channel("rotation/gamma_ch", "torque", t, data_y, model)]

    def twin(missing=None, with_rotation=True):
        keep = np.ones(len(t), bool)
        if missing is not None:
            keep[missing] = False
        y = structure + noise * rng.standard_normal(len(t))
        run = [_channel("straight/x_ch", "torque", t[keep], y[keep], model[keep])]
        if with_rotation:
            run.append(_channel("rotation/gamma_ch", "torque", t, y, model))
        return run

    runs = [twin(), twin(missing=40), twin(missing=41), twin(with_rotation=False)]
    one, _ = pair_channels(data, runs[0], TS)
    three, r = pair_channels(data, runs[0], TS, tuple(runs[1:3]))
    straight = three[0]
    assert not straight.fitted[40] and not straight.fitted[41] and straight.fitted.sum() == len(t) - 2
    rows = straight.fitted
    means = np.mean([run[0].residual[np.searchsorted(run[0].time, t[rows])] for run in runs[:3]], axis=0)
    np.testing.assert_allclose(straight.paired[rows], means)
    gap_one = np.std(one[0].residual[rows] - effect[rows])           # data's noise and one run's: √2
    gap_three = np.std(straight.residual[rows] - effect[rows])       # data's and three runs' mean: √(4/3)
    assert abs(gap_one - noise * np.sqrt(2)) < 0.05 and abs(gap_three - noise * np.sqrt(4 / 3)) < 0.05
    np.testing.assert_allclose(r[0].residual, 0.0, atol=1e-12)
    # the rotation's channel is missing from the last repeat: it stays unpaired
    partial, _ = pair_channels(data, runs[0], TS, (runs[1], runs[3]))
    assert partial[1].paired is None and partial[0].paired is not None


def test_a_run_that_recovered_from_a_limit_cycle_pairs_with_its_twin_shifted_by_the_recovery():
    """A campaign whose steering loop cycled at the torque limit records the held rows as a limit-cycle
    step and starts again: every later step lies the recovery's duration after the twin's same step (the
    twin, which probes its dead time from the start, has no recovery). The runs pair with that shift,
    each data sample against the twin's at the same point of the campaign; a shift that is not the same
    for every step does not pair."""
    recovery = 3.176
    data_segments = [{"name": "limit_cycle", "k": 1, "t_start": 0.0, "t_end": recovery}] + \
        [{**seg, "t_start": seg["t_start"] + recovery, "t_end": seg["t_end"] + recovery} for seg in SEGMENTS]
    data = {"settings": SETTINGS, "segments": data_segments}
    twin = {"settings": SETTINGS, "segments": SEGMENTS}
    assert pairing_shift(data, twin, TS) == -round(recovery / TS) and paired_runs(data, twin, TS)
    assert pairing_shift(twin, twin, TS) == 0
    uneven = [dict(seg) for seg in data_segments]
    uneven[-1]["t_end"] += 2 * TS                                     # its last step two cycles longer
    assert pairing_shift({**data, "segments": uneven}, twin, TS) is None

    rng = np.random.default_rng(9)
    t_twin = SEGMENTS[1]["t_start"] + TS * np.arange(1000)
    structure = 5.0 * np.sin(2 * np.pi * 0.9 * t_twin)
    twin_y = structure + 0.05 * rng.standard_normal(len(t_twin))
    data_y = structure + 0.05 * rng.standard_normal(len(t_twin))
    d, _ = pair_channels([_channel("steer_left/alpha_l", "torque", t_twin + recovery, data_y)],
                         [_channel("steer_left/alpha_l", "torque", t_twin, twin_y)], TS,
                         shifts=(pairing_shift(data, twin, TS),))
    assert d[0].fitted.all() and np.std(d[0].residual) < 0.1             # sample for sample, the structure gone
    unshifted, _ = pair_channels([_channel("steer_left/alpha_l", "torque", t_twin + recovery, data_y)],
                                 [_channel("steer_left/alpha_l", "torque", t_twin, twin_y)], TS)
    assert unshifted[0].fitted.sum() < len(t_twin) // 2                 # at the same times they hardly overlap
