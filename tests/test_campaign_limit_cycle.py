"""A campaign whose steering loop falls into a limit cycle at the torque limit (an actuator delay the default
gains cannot take) stops, probes the dead time and runs again (ident.campaign); a vehicle that never reaches
the limit records exactly what it records without the watch."""
import json
from pathlib import Path
from types import SimpleNamespace as NS

import numpy as np
import pytest

from qomni.ident.campaign import LIMIT_CYCLE_STEP, Campaign, CampaignAborted, CampaignSettings
from qomni.ident.controller import ControllerSettings
from qomni.ident.recording import SignalWriter, read_signals


@pytest.mark.slow
def test_a_limit_cycle_is_stopped_probed_and_the_campaign_runs_again_inside_the_limits(tmp_path):
    from qomni.suite.range_ends import campaign_margins

    # the longest realistic delay, no probe asked for: the default 45 rad/s loop cycles at the limit
    row = campaign_margins({"actuator_delay": {"delay": 0.02}}, tmp_path / "run", seed=3, probe=False)
    meta = json.loads((tmp_path / "run" / "metadata.json").read_text())
    assert row.completed, row                      # complete, never at the clip after the restart
    (cycle,) = meta["limit_cycles"]
    assert cycle["segment"] in ("rest", "steer_left") and cycle["steering_bandwidth"] == 45.0
    assert meta["probe"]["dead_time"] == pytest.approx(0.02, abs=0.004)
    assert meta["controller"]["probe"] and meta["controller"]["steering_bandwidth"] < 20.0
    names = [s["name"] for s in meta["segments"]]
    assert names[:3] == [LIMIT_CYCLE_STEP, "probe", "rest"] and names.count("steer_left") == 1
    signals = read_signals(tmp_path / "run" / "signals.csv")
    steps = signals.steps()
    assert steps[:3] == [LIMIT_CYCLE_STEP, "probe", "rest"] and "steer_left" in steps
    # the rows the limit cycle held are under its name, not the step it interrupted
    t_restart = next(s["t_start"] for s in meta["segments"] if s["name"] == "steer_left")
    assert signals.time[signals.step == "steer_left"].min() >= t_restart
    _pairs_with_its_twin_across_the_recovery(tmp_path / "run", meta, signals)


def _pairs_with_its_twin_across_the_recovery(run, meta, signals):
    """The twin of a recovered run probes from the start and never recovers: the runs pair with the
    recovery's duration as their shift, and at paired samples the steering follows the same trajectory."""
    from qomni.diagnosis.paired import pairing_shift
    from qomni.ident.identify import identify_run
    from qomni.twin import twin_reference

    identify_run(run)
    twin = twin_reference(run / "identification.json", run, run.parent / "twin")
    twin_meta = json.loads((twin / "metadata.json").read_text())
    assert LIMIT_CYCLE_STEP not in [s["name"] for s in twin_meta["segments"]]
    ts = 0.002
    recovery = next(s for s in meta["segments"] if s["name"] == LIMIT_CYCLE_STEP)
    shift = pairing_shift(meta, twin_meta, ts)
    assert shift == -round((recovery["t_end"] - recovery["t_start"]) / ts) != 0
    twin_signals = read_signals(twin / "signals.csv")
    data_rows, twin_rows = signals.step == "steer_left", twin_signals.step == "steer_left"
    k_data = np.rint(signals.time[data_rows] / ts).astype(int)
    k_twin = np.rint(twin_signals.time[twin_rows] / ts).astype(int)
    common, i_data, i_twin = np.intersect1d(k_data + shift, k_twin, return_indices=True)
    assert len(common) == data_rows.sum()
    gap = np.abs(signals.alpha[data_rows][i_data] - twin_signals.alpha[twin_rows][i_twin]).max()
    assert gap < 0.02                       # the same point of the steering excitation, sample for sample


@pytest.mark.slow
def test_a_vehicle_that_never_reaches_the_limit_records_the_same_with_and_without_the_watch(tmp_path):
    from qomni.embedded import embedded_vehicle
    from qomni.emulator.description import VehicleDescription
    from qomni.emulator.effects import EffectSet

    description = VehicleDescription.load()
    recorded = []
    for watch in (True, False):
        run = tmp_path / f"watch_{watch}"
        campaign = Campaign(description.datasheet, run, CampaignSettings.quick(seed=3),
                            ControllerSettings(probe_on_limit_cycle=watch))
        # 4 ms: the loop keeps a few degrees of margin and stays off the limit
        delayed = EffectSet.from_dict({"actuator_delay": {"delay": 0.004}})
        with embedded_vehicle(description, seed=3, effects=delayed) as link:
            meta = campaign.run(link)
        assert "limit_cycles" not in meta
        recorded.append((run / "signals.csv").read_bytes())
    assert recorded[0] == recorded[1]


class _Rattling:
    """A vehicle whose steering sensors jump ±0.4 rad every cycle whatever it is commanded: any loop
    saturates on it."""

    cycle_time = 0.002

    def __init__(self):
        self.n = 0

    def exchange(self, u):
        self.n += 1
        a = 0.4 * (-1) ** self.n
        return NS(time=self.n * self.cycle_time, motor_position=np.zeros(4), motor_velocity=np.zeros(4),
                  motor_torque=np.asarray(u, float), alpha=np.array([a, a]))

    def stop(self):
        pass


def test_a_third_limit_cycle_aborts_the_campaign_and_says_so(tmp_path):
    from qomni.emulator.description import VehicleDescription

    sheet = VehicleDescription.load().datasheet
    campaign = Campaign(sheet, tmp_path / "run", CampaignSettings.quick(seed=3), ControllerSettings())
    with pytest.raises(CampaignAborted, match="limit cycle at the torque limit"):
        campaign.run(_Rattling())
    meta = json.loads((tmp_path / "run" / "metadata.json").read_text())
    assert meta["status"].startswith("aborted") and len(meta["limit_cycles"]) == 3
    # the probe's bandwidth, then the one designed for max_dead_time, each tried once
    assert meta["limit_cycles"][0]["steering_bandwidth"] == 45.0
    assert meta["limit_cycles"][2]["steering_bandwidth"] < meta["limit_cycles"][0]["steering_bandwidth"]


def test_held_rows_are_written_in_order_under_the_name_given_at_release(tmp_path):
    m = NS(time=0.0, alpha=np.zeros(2), motor_position=np.zeros(4), motor_velocity=np.zeros(4),
           motor_torque=np.zeros(4))
    with SignalWriter(tmp_path / "signals.csv") as w:
        w.write("rest", 1, m, np.zeros(4))
        w.hold()
        w.write("steer_left", 1, NS(**{**vars(m), "time": 0.002}), np.zeros(4))
        w.write("steer_left", 1, NS(**{**vars(m), "time": 0.004}), np.zeros(4))
        assert w.rows == 1
        w.release(LIMIT_CYCLE_STEP)
        w.write("probe", 1, NS(**{**vars(m), "time": 0.006}), np.zeros(4))
        w.hold()
        w.write("rest", 1, NS(**{**vars(m), "time": 0.008}), np.zeros(4))
    s = read_signals(tmp_path / "signals.csv")                 # closing writes what was still held
    assert list(s.step) == ["rest", LIMIT_CYCLE_STEP, LIMIT_CYCLE_STEP, "probe", "rest"]
    assert np.all(np.diff(s.time) > 0)


def test_the_twin_repeats_a_recovered_runs_probe_and_bandwidth_and_never_watches():
    from qomni.twin import _controller_of

    recovered = {"controller": {"steering_bandwidth": 15.9, "probe": True, "probe_on_limit_cycle": True}}
    c = _controller_of(recovered, Path("run/metadata.json"))
    assert c.probe and not c.probe_retunes and not c.probe_on_limit_cycle and c.steering_bandwidth == 15.9
    assert not _controller_of({}, Path("run/metadata.json")).probe_on_limit_cycle
