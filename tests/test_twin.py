"""The digital twin (qomni.twin): the emulator configured with an identification, on the data sheet's
vehicle, with the paper's idealised bodies; written as a vehicle file the emulator reads back."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from doubles import identification
from qomni.conventions import PARAMETER_NAMES
from qomni.datasheet import DataSheet
from qomni.emulator.description import VehicleDescription
from qomni.emulator.effects import EffectSet
from qomni.emulator.vehicle import Emulator
from qomni.twin import TwinError, reference_seed, twin_description, twin_toml

PROTOTYPE_TOML = Path(__file__).resolve().parents[1] / "emulator" / "data" / "prototype.toml"


def test_the_twins_truth_is_the_identification_on_the_data_sheets_vehicle(tmp_path):
    result, sheet = identification(), DataSheet.load()
    desc = twin_description(result, sheet)
    np.testing.assert_array_equal([getattr(desc.truth, n) for n in PARAMETER_NAMES], result.p)
    assert desc.geometry == sheet.geometry and desc.drive == sheet.drive
    path = tmp_path / "twin.toml"
    path.write_text(twin_toml(desc))
    again = VehicleDescription.load(path)
    assert again.truth == desc.truth and again.datasheet.nominal == sheet.nominal
    assert DataSheet.load(path).geometry == sheet.geometry            # the file is a data sheet too


def test_the_twin_runs_as_the_ideal_vehicle_with_the_identified_mass(tmp_path):
    desc = twin_description(identification(), DataSheet.load())
    with Emulator(desc, effects=EffectSet.ideal(), seed=1) as emu:
        emu.set_motor_torques(np.zeros(4))
        emu.step(0.01)
        assert emu.effects.names == ()


def test_a_smaller_vehicles_twin_gives_its_forks_a_share_of_its_steering_inertia():
    """Identified steering inertias a third of the prototype's (C_r/2 = 0.07 kg m², the prototype's wheel
    alone): the twin's wheels take 3/4 of the smaller unit's inertia, no less than 0.55 B_w, so that the twin
    is a vehicle; the prototype's twin keeps the prototype's wheel. Inertias that cannot hold a wheel of
    the identified B_w are no twin."""
    from qomni.emulator.effects.base import IDEAL_WHEEL_MASS, ideal_plan
    from qomni.emulator.urdf import body_inertias

    sheet, prototype = DataSheet.load(), VehicleDescription.load()
    assert twin_description(identification(), sheet).body.wheel_transverse_inertia == \
        prototype.body.wheel_transverse_inertia
    result = identification()
    small = replace(result, values={**result.values, "C_l": 0.16, "C_r": 0.14}, B_w=0.06)
    desc = twin_description(small, sheet)
    unit = 0.07 - IDEAL_WHEEL_MASS * sheet.geometry.a ** 2
    assert desc.body.wheel_transverse_inertia == pytest.approx(0.75 * unit)
    forks = body_inertias(desc, ideal_plan(desc)).fork_izz
    assert min(forks.values()) == pytest.approx(0.25 * unit) and max(forks.values()) > min(forks.values())
    with Emulator(desc, effects=EffectSet.ideal(), seed=1) as emu:
        emu.step(0.01)
    with pytest.raises(TwinError, match="no rigid-body vehicle.*too small"):
        twin_description(replace(small, B_w=0.15), sheet)          # 0.55 B_w beyond what a unit holds


def test_a_larger_vehicles_twin_has_wheels_the_physics_engine_takes():
    """B_w = 0.5 kg m² and steering inertias of 1.5 kg m² (a larger vehicle's wheels and units): the
    prototype's 0.07 kg m² about a diameter would break the triangle inequality and B_w/2 is a disc of no
    width, whose tensor PyBullet zeroes; the twin's wheels have 0.55 B_w and keep their inertia in the
    engine."""
    result = identification()
    larger = replace(result, values={**result.values, "C_l": 1.5, "C_r": 1.5}, B_w=0.5)
    desc = twin_description(larger, DataSheet.load())
    assert desc.body.wheel_transverse_inertia == pytest.approx(0.275)
    with Emulator(desc, effects=EffectSet.ideal(), seed=1) as emu:
        pb = emu._pb
        names = {pb.getJointInfo(emu.body, j)[12].decode(): j for j in range(pb.getNumJoints(emu.body))}
        inertia = pb.getDynamicsInfo(emu.body, names["wheel_fl"])[2]
    assert inertia == pytest.approx((0.275, 0.5, 0.275), rel=1e-6)


def test_the_reference_runs_noise_is_drawn_apart_from_the_campaigns_seed():
    seeds = [reference_seed(s) for s in range(50)]
    assert len(set(seeds)) == 50 and not set(seeds) & set(range(50))
    assert reference_seed(7) == reference_seed(7) and 0 <= reference_seed(7) < 2 ** 32


def test_the_twins_repeats_draw_their_noise_apart_from_each_other_and_from_the_campaign():
    repeats = {(s, k): reference_seed(s, k) for s in range(20) for k in range(4)}
    assert len(set(repeats.values())) == len(repeats)              # every (campaign, run) its own stream
    assert not set(repeats.values()) & set(range(20))
    assert all(reference_seed(s) == repeats[s, 0] for s in range(20))   # run 0 is the single reference run
    with pytest.raises(ValueError, match="negative"):
        reference_seed(3, -1)


@pytest.fixture(scope="module")
def identified_run(tmp_path_factory):
    """A quick campaign of seed 11 on the ideal prototype, identified (``identification.json`` beside it)."""
    from qomni.embedded import embedded_vehicle
    from qomni.ident.campaign import Campaign, CampaignSettings
    from qomni.ident.identify import identify_run

    run = tmp_path_factory.mktemp("twin") / "run"
    settings = replace(CampaignSettings.quick(), seed=11)
    with embedded_vehicle(VehicleDescription.load(), seed=11, effects=EffectSet.ideal()) as client:
        Campaign(DataSheet.load(), run, settings, source="test").run(client)
    identify_run(run)
    return run


class _Stop(Exception):
    """Raised by the emulator stand-in of :func:`seeds_handed_to_the_emulator` once it has its seed."""


@pytest.fixture
def seeds_handed_to_the_emulator(monkeypatch):
    """The noise seeds the twin's campaigns hand the emulator, in order: the emulator factory is replaced by
    one that records its seed and raises :class:`_Stop` instead of driving a campaign."""
    import qomni.embedded

    seen = []

    def vehicle(description, *, seed=0, **kw):
        seen.append(seed)
        raise _Stop

    monkeypatch.setattr(qomni.embedded, "embedded_vehicle", vehicle)
    return seen


def test_the_twins_reference_run_draws_its_noise_from_its_own_stream(identified_run, tmp_path,
                                                                       seeds_handed_to_the_emulator):
    """The twin's campaign keeps the data run's seed (excitation, segments); the emulator it drives draws
    ripple and sensor noise from ``reference_seed`` of it, never the data run's seed; a run stopped before
    its end leaves no stamp a later diagnosis could take for a finished reference."""
    import json

    from qomni.ident.rundir import TWIN_STAMP
    from qomni.twin import twin_reference

    run = identified_run
    with pytest.raises(_Stop):
        twin_reference(run / "identification.json", run, tmp_path / "ref")
    seen = seeds_handed_to_the_emulator
    assert seen == [reference_seed(11)] and seen[0] != 11
    stamp = tmp_path / "ref" / TWIN_STAMP
    assert not stamp.exists()                                    # an unfinished run is never a cache hit
    assert json.loads((run / "metadata.json").read_text())["settings"]["seed"] == 11


def test_each_of_the_twins_runs_has_its_own_directory_and_noise_stream(identified_run, tmp_path, monkeypatch,
                                                                       seeds_handed_to_the_emulator):
    """``twin_references`` builds the twin once and runs the same campaign once per run number, run 0 in the
    cache and each repeat in a sibling, every one on its own noise seed."""
    import qomni.twin
    from qomni.twin import twin_references

    run = identified_run
    calls, built = [], []
    real_run, real_twin = qomni.twin._reference_run, qomni.twin._twin_of

    def recorded(campaign, cache, k, on_progress):
        calls.append((Path(cache).name, k))
        with pytest.raises(_Stop):
            real_run(campaign, cache, k, on_progress)
        return Path(cache)

    def twin_of(*args):
        built.append(args)
        return real_twin(*args)

    monkeypatch.setattr(qomni.twin, "_reference_run", recorded)
    monkeypatch.setattr(qomni.twin, "_twin_of", twin_of)
    dirs = twin_references(run / "identification.json", run, tmp_path / "twin_reference", runs=3)
    assert [d.name for d in dirs] == ["twin_reference", "twin_reference_1", "twin_reference_2"]
    assert calls == [("twin_reference", 0), ("twin_reference_1", 1), ("twin_reference_2", 2)]
    assert seeds_handed_to_the_emulator == [reference_seed(11, k) for k in range(3)]
    assert len(built) == 1
    with pytest.raises(ValueError, match="at least one"):
        twin_references(run / "identification.json", run, tmp_path / "none", runs=0)


def _cut(signals: Path) -> None:
    """``signals`` cut in the middle of a line, as a recording that stopped being written."""
    text = signals.read_bytes()
    signals.write_bytes(text[:len(text) // 2 + 37])


def test_a_data_run_cut_short_is_refused_before_the_twin_drives(identified_run, tmp_path,
                                                                 seeds_handed_to_the_emulator):
    import shutil

    from qomni.twin import twin_reference

    data = tmp_path / "data"
    shutil.copytree(identified_run, data)
    _cut(data / "signals.csv")
    with pytest.raises(ValueError, match="signals.csv"):
        twin_reference(identified_run / "identification.json", data, tmp_path / "ref")
    assert seeds_handed_to_the_emulator == [] and not (tmp_path / "ref").exists()


def test_a_cached_reference_whose_recording_went_bad_is_no_cache_hit(identified_run, tmp_path):
    """The stamp says which twin and campaign a cached run is; the run is reused only while its files
    read back whole and as they were written: a recording edited into another valid one is no hit."""
    import json
    import shutil

    from qomni.ident.rundir import TWIN_STAMP
    from qomni.twin import _finished, _stamp

    cache, key = tmp_path / "twin_reference", {"twin": "a twin", "noise_seed": 5}
    shutil.copytree(identified_run, cache)
    (cache / TWIN_STAMP).write_text(json.dumps(key))
    assert not _finished(cache, key)                            # a stamp that vouches for no recording
    (cache / TWIN_STAMP).write_text(json.dumps(_stamp(cache, key)))
    assert _finished(cache, key) and not _finished(cache, {**key, "noise_seed": 6})
    signals = cache / "signals.csv"
    written = signals.read_bytes()
    header, first, *rest = written.decode().splitlines()
    cells = first.split(",")
    cells[-1] = repr(float(cells[-1]) * 1.3)                    # one commanded torque, still a valid file
    signals.write_text("\n".join([header, ",".join(cells), *rest]) + "\n")
    assert not _finished(cache, key)
    signals.write_bytes(written)
    assert _finished(cache, key)
    _cut(cache / "signals.csv")
    assert not _finished(cache, key)
    (cache / TWIN_STAMP).write_text("{")
    assert not _finished(cache, key)


def test_a_decoded_log_without_its_runs_metadata_has_neither_twin_nor_diagnosis(identified_run, tmp_path,
                                                                                 seeds_handed_to_the_emulator):
    """A bus log decoded without its run's metadata.json has no campaign settings and no step names (every
    row is step 'recorded'): the twin cannot drive its campaign, and the diagnosis has no channel to read.
    Both say so instead of diagnosing nothing as "no significant unmodelled effect"."""
    import json
    import shutil

    from qomni.diagnosis.diagnose import diagnose_paths
    from qomni.ident.rundir import RunDirectoryError
    from qomni.twin import twin_reference

    data = tmp_path / "decoded"
    shutil.copytree(identified_run, data)
    lines = (data / "signals.csv").read_text().splitlines()
    rows = [line.split(",", 2) for line in lines[1:]]
    decoded = [lines[0], *(f"{t},recorded,{rest}" for t, _, rest in rows)]
    (data / "signals.csv").write_text("\n".join(decoded) + "\n")
    meta = json.loads((data / "metadata.json").read_text())
    meta = {k: v for k, v in meta.items() if k not in ("settings", "status")} | {"segments": []}
    (data / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(TwinError, match="records no campaign settings"):
        twin_reference(identified_run / "identification.json", data, tmp_path / "ref")
    assert seeds_handed_to_the_emulator == []
    with pytest.raises(RunDirectoryError, match="none of the campaign's steps"):
        diagnose_paths(identified_run / "identification.json", data, reference_dir=identified_run)


def test_a_run_stopped_in_its_lane_change_is_diagnosed_paired_with_its_twin_over_the_steps_it_completed(
        identified_run, tmp_path):
    """A campaign stopped during its lane change keeps the rows it recorded, and its metadata lists the
    segments it completed with an aborted status (as ``Campaign.run`` writes them). Its twin drives those
    segments and no more; the diagnosis pairs the two over the data's steps and, on the ideal vehicle,
    names nothing."""
    import json
    import shutil

    from qomni.diagnosis.diagnose import diagnose_paths
    from qomni.twin import twin_reference

    data = tmp_path / "stopped"
    shutil.copytree(identified_run, data)
    meta = json.loads((data / "metadata.json").read_text())
    names = [seg["name"] for seg in meta["segments"]]
    lane = meta["segments"][names.index("lane_change")]
    stop = 0.5 * (lane["t_start"] + lane["t_end"])
    meta = {**meta, "segments": meta["segments"][:names.index("lane_change")],
            "status": "aborted: KeyboardInterrupt: "}
    (data / "metadata.json").write_text(json.dumps(meta))
    lines = (data / "signals.csv").read_text().splitlines()
    kept = [lines[0], *(line for line in lines[1:] if float(line.split(",", 1)[0]) < stop)]
    (data / "signals.csv").write_text("\n".join(kept) + "\n")

    reference = twin_reference(identified_run / "identification.json", data, tmp_path / "twin_reference")
    twin_meta = json.loads((reference / "metadata.json").read_text())
    assert twin_meta["status"] == "complete"
    assert [seg["name"] for seg in twin_meta["segments"]] == [seg["name"] for seg in meta["segments"]]
    d = diagnose_paths(identified_run / "identification.json", data, reference_dir=reference, simulate=False)
    assert d.data_run["status"].startswith("aborted")
    assert {name.split("/")[0] for name in d.paired_channels} == {"steer_left", "steer_right", "straight",
                                                                  "rotation"}
    assert d.verdict == "no significant unmodelled effect"


def test_the_reference_and_held_out_runs_are_other_runs_of_the_datas_vehicle(identified_run, tmp_path):
    """The data against themselves leave no residual; a run of another vehicle (another data sheet) leaves
    the difference of two vehicles: both refused, naming the run and what differs."""
    import json
    import shutil

    from qomni.diagnosis.diagnose import diagnose_paths
    from qomni.ident.rundir import RunDirectoryError

    model = identified_run / "identification.json"
    copy = tmp_path / "copy"
    shutil.copytree(identified_run, copy)
    for kwargs in ({"reference_dir": identified_run}, {"reference_dir": copy}, {"holdout_dir": copy}):
        with pytest.raises(RunDirectoryError, match="the same recording as the data"):
            diagnose_paths(model, identified_run, simulate=False, **kwargs)
    other = tmp_path / "other"
    shutil.copytree(identified_run, other)
    meta = json.loads((other / "metadata.json").read_text())
    meta["datasheet"]["geometry"]["l"] *= 1.2
    (other / "metadata.json").write_text(json.dumps(meta))
    lines = (other / "signals.csv").read_text().splitlines()
    (other / "signals.csv").write_text("\n".join(lines[:-1]) + "\n")         # another recording
    for kwargs in ({"reference_dir": other}, {"holdout_dir": other}):
        with pytest.raises(RunDirectoryError, match=r"data sheet differs from the data's in geometry.l"):
            diagnose_paths(model, identified_run, simulate=False, **kwargs)


def test_a_model_of_another_vehicle_is_refused_before_its_twin_runs(identified_run, tmp_path, monkeypatch):
    """Two vehicles differ in every parameter, and the diagnosis described that difference with the
    hypothesis that fits it best (a 464 kg heavier vehicle's model on the prototype's run: a floor incline,
    p = 2·10⁻⁶). identify records the vehicle's name and data sheet; a model of another name, geometry or drive
    is refused by the API and by the CLI before the twin's campaign, unless --other-vehicle."""
    import json
    import shutil

    from typer.testing import CliRunner

    from qomni.cli import app
    from qomni.diagnosis.diagnose import check_model_vehicle, diagnose_paths
    from qomni.ident.rundir import RunDirectoryError

    model = identified_run / "identification.json"
    recorded = json.loads(model.read_text())["run"]
    assert recorded["vehicle"] == "prototype" and recorded["datasheet"]["geometry"]["r"] == DataSheet.load().geometry.r
    other = tmp_path / "other"
    shutil.copytree(identified_run, other)
    (other / "identification.json").unlink()
    lines = (other / "signals.csv").read_text().splitlines()
    (other / "signals.csv").write_text("\n".join(lines[:-1]) + "\n")         # another recording
    meta = json.loads((other / "metadata.json").read_text())
    (other / "metadata.json").write_text(json.dumps({**meta, "vehicle": "heavy_platform"}))
    with pytest.raises(RunDirectoryError, match=r"identified on vehicle 'prototype', the data .* is "
                                                r"'heavy_platform' \(they differ in vehicle name"):
        diagnose_paths(model, other, simulate=False)
    result = CliRunner().invoke(app, ["diagnose", "--model", str(model), "--data", str(other), "--out",
                                      str(tmp_path / "gap")])
    assert result.exit_code == 2 and "--other-vehicle" in result.output and not (tmp_path / "gap").exists()
    import qomni.diagnosis.diagnose as diagnose_module

    monkeypatch.setattr(diagnose_module, "diagnose", lambda *args, **kwargs: "diagnosed")   # the flag lets it in
    assert diagnose_paths(model, other, simulate=False, other_vehicle=True) == "diagnosed"
    monkeypatch.undo()
    meta["datasheet"]["geometry"]["r"] = 0.2
    (other / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(RunDirectoryError, match=r"they differ in geometry.r\)"):
        check_model_vehicle(model, other)
    legacy = tmp_path / "legacy.json"                  # no vehicle recorded, no metadata.json beside it
    data = json.loads(model.read_text())
    data["run"] = {k: v for k, v in data["run"].items() if k not in ("vehicle", "datasheet")}
    legacy.write_text(json.dumps(data))
    check_model_vehicle(legacy, other)


def test_a_twin_data_sheet_that_is_not_the_datas_vehicle_is_refused(identified_run, tmp_path):
    from qomni.twin import twin_reference

    sheet = tmp_path / "other.toml"
    text = PROTOTYPE_TOML.read_text()
    sheet.write_text(text.replace("i_G = 25.0", "i_G = 50.0", 1))
    assert sheet.read_text() != text
    with pytest.raises(TwinError, match=r"differs from the data sheet the data's run recorded .* in drive.i_G"):
        twin_reference(identified_run / "identification.json", identified_run, tmp_path / "ref", datasheet=sheet)
    assert not (tmp_path / "ref").exists()


@pytest.mark.parametrize("name, value", [("m_ch", -1.0), ("C_l", 0.0), ("d_cw", -0.1)])
def test_an_unphysical_identification_has_no_twin(name, value):
    result = identification()
    if name in result.values:
        result = replace(result, values={**result.values, name: value})
    with pytest.raises(TwinError, match=name):
        twin_description(result, DataSheet.load())


@pytest.mark.parametrize("name, factor", [("m_ch", 1000.0), ("C_ch", 0.05), ("d_vw", 20.0)])
def test_an_identification_orders_of_magnitude_off_its_data_sheet_has_no_twin(name, factor):
    # another unit (g for kg) or another vehicle's file: the twin would drive a vehicle nobody has
    result = identification()
    result = replace(result, values={**result.values, name: factor * result.values[name]})
    with pytest.raises(TwinError, match=rf"identified {name} = .* more than 10 × off the data sheet's nominal"):
        twin_description(result, DataSheet.load())


def test_the_twin_repeats_the_data_runs_controller_with_its_recorded_steering_bandwidth():
    """A data run that probed its dead time recorded the bandwidth it then used; the twin probes as well (the
    same campaign, probe step included) but keeps that bandwidth instead of retuning to its own reading. A
    recorded value no controller runs with is refused naming the file and key."""
    from qomni.twin import TwinError, _controller_of

    src = Path("run/metadata.json")
    c = _controller_of({"controller": {"probe": True, "steering_bandwidth": 13.4, "retired_setting": 1}}, src)
    assert c.probe and c.steering_bandwidth == 13.4 and not c.probe_retunes
    assert _controller_of({}, src).steering_bandwidth == 45.0 and not _controller_of({}, src).probe
    with pytest.raises(TwinError, match="run/metadata.json: controller.steering_bandwidth must be a number"):
        _controller_of({"controller": {"steering_bandwidth": "x"}}, src)


@pytest.mark.slow
def test_the_twin_repeats_the_data_runs_campaign_settings_and_drives_no_arcs_a_run_did_not_record():
    from qomni.ident.campaign import CampaignSettings
    from qomni.twin import TwinError, _settings_of

    src = Path("run/metadata.json")
    assert _settings_of({"settings": {"seed": 4, "arc_duration": 10.0}}, src).arc_duration == 10.0
    older = _settings_of({"settings": {"seed": 4}}, src)
    assert older.arc_duration == 0.0 and older.lane_changes == 1 and older.seed == 4
    assert older.excitation == "richness"           # recorded before the min_cond design existed
    assert _settings_of({"settings": {**CampaignSettings().__dict__}}, src) == CampaignSettings()
    with pytest.raises(TwinError, match="run/metadata.json: .*retired_setting"):
        _settings_of({"settings": {"retired_setting": 1}}, src)


def test_a_model_that_is_not_physical_gets_the_twin_of_its_runs_consistent_estimate(identified_run, tmp_path):
    """A model identified on the data run with a negative friction (as a long actuator delay gives) is not a
    vehicle: the twin is made from the same run re-identified with the consistent estimator, and says so.
    A model from another run is refused as before."""
    import json

    from qomni.twin import _twin_of

    run = identified_run
    data = json.loads((run / "identification.json").read_text())
    data["parameters"]["d_vl"]["value"] = -2.0
    model = tmp_path / "model.json"
    model.write_text(json.dumps(data))
    sheet = DataSheet.load()
    description, parameters = _twin_of(model, run, sheet)
    assert "consistent estimator" in parameters and "d_vl = -2.0" in parameters
    assert description.truth.d_vl == pytest.approx(json.loads((run / "identification.json").read_text())
                                                   ["parameters"]["d_vl"]["value"])  # WLS was admissible
    data["run"]["signals_sha256"] = "0" * 64                    # identified on another run
    model.write_text(json.dumps(data))
    with pytest.raises(TwinError, match="negative friction"):
        _twin_of(model, run, sheet)
