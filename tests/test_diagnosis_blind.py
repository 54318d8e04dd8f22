"""The gap diagnosis, blind: quick campaigns on emulators with a known effect (none; one; two at once),
diagnosed against a model identified on the ideal emulator, told nothing about the effects.

The full suite (every effect × 5 seeds × 2 magnitudes) is ``python benchmarks/blind_suite.py``.
"""
import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from own_twin import diagnose_against_own_twin
from qomni.blind_suite import Case, run_suite, score

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


@pytest.fixture(scope="module")
def suite(tmp_path_factory):
    work = tmp_path_factory.mktemp("blind")
    cases = [
        Case("ideal", {}, [], seed=31),
        Case("torque", {"torque_constant_error": {"drive": "fl", "factor": 0.88}},
             ["torque_constant_error"], seed=32),
        Case("incline+radius", {"incline": {"angle": 0.02, "uphill_heading": 2.8450},
                                "wheel_radius": {"radius": 0.096}},
             ["incline", "wheel_radius"], seed=33),
        Case("slip", {"tire_slip": {"cornering_stiffness": 6000.0}}, ["tire_slip"], seed=34),
    ]
    results = {r.case.name: r for r in run_suite(cases, work, quick=True, workers=2, reference="ideal")}
    return work, results


@pytest.fixture(scope="module")
def ideal_twin(suite):
    """The ideal case's twin campaign, run where ``qomni diagnose --out RUN/twin_gap`` keeps its cache; the
    tests diagnosing the case against its twin reuse it instead of running it again."""
    from qomni.twin import twin_reference

    run = suite[0] / "ideal"
    return twin_reference(run / "identification.json", run, run / "twin_gap" / "twin_reference")


def test_no_case_failed(suite):
    _, results = suite
    assert not [r.error for r in results.values() if r.error]


def test_ideal_emulator_gives_no_significant_effect(suite):
    work, results = suite
    r = results["ideal"]
    assert r.accepted == []
    assert r.verdict == "no significant unmodelled effect"
    gap = json.loads((work / "ideal" / "gap" / "gap.json").read_text())
    assert gap["verdict"] == "no significant unmodelled effect"
    assert not any(e["significant"] for e in gap["effects"])


def test_single_effect_is_ranked_first_with_its_magnitude(suite):
    work, results = suite
    r = results["torque"]
    assert r.accepted[:1] == ["torque_constant_error"] and r.false_positives == []
    gap = json.loads((work / "torque" / "gap" / "gap.json").read_text())
    top = gap["effects"][0]
    assert top["name"] == "torque_constant_error" and top["variant"] == "drive fl"
    assert top["significant"]
    assert top["ci"][0] <= top["magnitude"] <= top["ci"][1]
    assert top["magnitude"] == pytest.approx(0.88 - 1, abs=0.02)      # factor − 1
    assert top["holdout_shrink"] >= 0.5
    for key in ("name", "magnitude", "ci", "significant", "holdout_shrink", "holdout_shrink_beyond_base_fit",
                "holdout_shrink_beyond_reference"):
        assert all(key in e for e in gap["effects"])
    # the shrink of adding the effect starts from the model as identified's held-out residual in the
    # same channel; the base fit, with the base parameters moved within their prior, leaves less there
    before = top["holdout_channels"][top["affected_channel"]]["rms_before"]
    assert before == pytest.approx(gap["model_holdout_rms"][top["affected_channel"]])
    assert gap["base_fit_holdout_rms"][top["affected_channel"]] < before
    assert top["holdout_shrink_beyond_base_fit"] >= 0.5


def test_tyre_slip_is_named_from_the_rolling_constraints_with_its_cornering_stiffness(suite):
    work, results = suite
    r = results["slip"]
    assert r.accepted == ["tire_slip"], r.verdict
    gap = json.loads((work / "slip" / "gap" / "gap.json").read_text())
    top = gap["effects"][0]
    assert top["name"] == "tire_slip" and top["significant"]
    assert 1 / top["magnitude"] == pytest.approx(6000.0, rel=0.1)          # C_α, N/rad
    assert top["affected_channel"].startswith("rotation/rolling_")
    assert top["holdout_shrink"] >= 0.5


def test_two_effects_at_once_are_both_named(suite):
    work, results = suite
    r = results["incline+radius"]
    assert set(r.accepted) == {"incline", "wheel_radius"}, r.verdict
    gap = json.loads((work / "incline+radius" / "gap" / "gap.json").read_text())
    radius = next(e for e in gap["accepted"] if e["name"] == "wheel_radius")
    assert radius["magnitude"] == pytest.approx(0.096, abs=0.001)
    assert all(e["holdout_shrink"] >= 0.5 for e in gap["accepted"])


def test_score_counts_top1_and_false_positives(suite):
    _, results = suite
    s = score(list(results.values()))
    assert s["top1_accuracy"] == 1.0
    assert s["ideal_false_positives"] == 0
    assert s["pairs_both_named"] == 1
    # the ideal case sets each channel's noise floor; the faulty drive's residual lies well above it
    assert set(results["ideal"].holdout_rms) >= {"straight/x_ch", "rotation/gamma_ch"}
    # a model of another run leaves the lifted wheels out: it has not taken the ground's share of their
    # friction, which the ground's channels show
    assert "lifted/beta" not in results["ideal"].holdout_rms
    assert s["noise_floor"]["rotation/gamma_ch"] == pytest.approx(
        results["ideal"].model_holdout_rms["rotation/gamma_ch"])
    torque = s["per_effect"]["torque_constant_error"]
    assert torque["median_excess_shrink"] >= torque["median_holdout_shrink"] >= 0.5
    # the gap beyond the case's own reference run (here the ideal vehicle's) shrinks at least as much
    assert results["torque"].true_shrink["torque_constant_error"]["reference_rms"] > 0
    assert torque["median_gap_shrink"] >= torque["median_holdout_shrink"]


def test_run_directories_hold_no_effect(suite):
    work, _ = suite
    for case in ("torque", "incline+radius"):
        names = {p.name for p in (work / case).rglob("*")}
        assert not any("effect" in n for n in names)
        meta = (work / case / "metadata.json").read_text()
        assert "torque_constant_error" not in meta and "wheel_radius" not in meta and "incline" not in meta


def test_diagnose_cli_reports_a_missing_model_clearly(tmp_path, suite):
    work, _ = suite
    out = subprocess.run([sys.executable, "-m", "qomni.cli", "diagnose", "--model", str(tmp_path / "none"),
                          "--data", str(work / "ideal"), "--out", str(tmp_path / "d")],
                         capture_output=True, text=True)
    assert out.returncode == 2
    assert "does not exist" in " ".join((out.stdout + out.stderr).split())  # rich wraps lines
    assert not (tmp_path / "d").exists()


@pytest.mark.slow
def test_a_run_diagnosed_against_its_own_digital_twin_names_no_effect_that_is_not_there(suite, ideal_twin):
    """The real user's mode: no ideal reference, only the run, the model identified from it and the model's
    digital twin, whose campaign (same settings) the CLI runs and keeps next to the report."""
    work, _ = suite
    run, out = work / "ideal", work / "ideal" / "twin_gap"
    gap = diagnose_against_own_twin(run, out)
    assert gap["reference"] == str(out / "twin_reference") and gap["data_run"]["status"] == "complete"
    assert gap["reference_kind"] == "digital twin"
    assert gap["verdict"] == "no significant unmodelled effect", gap["verdict"]
    # the bus reads no report lag behind the set-point: the ground's data are not asked for one
    assert gap["data_run"]["setpoint_lag"]["cycles"] < 0.1
    assert gap["data_run"]["report_lag_hypothesis"].startswith("not fitted")
    assert "torque_report_lag" not in {e["name"] for e in gap["effects"]}
    twin_meta = json.loads((out / "twin_reference" / "metadata.json").read_text())
    data_meta = json.loads((run / "metadata.json").read_text())
    assert twin_meta["settings"] == data_meta["settings"] and twin_meta["status"] == "complete"
    # the twin ran the data's campaign sample for sample: every torque channel is diagnosed beyond it
    assert twin_meta["segments"] == data_meta["segments"]
    torque = {c for c in gap["model_holdout_rms"] if "/kinematic_" not in c and "/rolling_" not in c}
    # (but the lifted wheels' channel: the twin's campaign does not lift its vehicle)
    assert "lifted/beta" in torque and set(gap["paired_channels"]) == torque - {"lifted/beta"}


@pytest.mark.slow
def test_repeats_of_the_twins_campaign_lower_the_paired_floor_without_naming_an_effect(suite, ideal_twin,
                                                                                       tmp_path):
    """``--twin-runs 3``: the twin's campaign run on three noise draws (the first is the single reference
    run, the others its siblings); the paired channels are diagnosed beyond the runs' mean residual,
    whose noise is a third of one run's, so the clean run's held-out residual left in them is lower than
    against the single run. A repeat that is not the data's campaign is refused, and so are repeats with
    a reference that is not the twin."""
    from qomni.diagnosis.diagnose import diagnose_paths
    from qomni.diagnosis.paired import PairingError

    work, _ = suite
    run, out = work / "ideal", tmp_path / "twin_gap3"
    shutil.copytree(ideal_twin, out / "twin_reference")          # run 0 from the cache; runs 1 and 2 afresh
    cached = (out / "twin_reference" / "signals.csv").stat().st_mtime_ns
    result = subprocess.run([sys.executable, "-m", "qomni.cli", "diagnose", "--model",
                             str(run / "identification.json"), "--data", str(run), "--out", str(out),
                             "--no-simulate", "--twin-runs", "3"], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
    gap = json.loads((out / "gap.json").read_text())
    assert gap["reference"] == str(out / "twin_reference")
    assert gap["reference_repeats"] == [str(out / "twin_reference_1"), str(out / "twin_reference_2")]
    assert (out / "twin_reference" / "signals.csv").stat().st_mtime_ns == cached    # reused, not run again
    assert gap["verdict"] == "no significant unmodelled effect", gap["verdict"]
    metas = [json.loads((out / d / "metadata.json").read_text())
             for d in ("twin_reference", "twin_reference_1", "twin_reference_2")]
    assert all(m["settings"] == metas[0]["settings"] and m["segments"] == metas[0]["segments"] for m in metas)
    signals = [(out / d / "signals.csv").read_bytes() for d in ("twin_reference", "twin_reference_1")]
    assert signals[0] != signals[1]                                        # another noise draw
    single = diagnose_paths(run / "identification.json", run, reference_dir=out / "twin_reference",
                            simulate=False)
    paired = gap["paired_channels"]
    assert paired and set(paired) == set(single.paired_channels)
    floor = lambda rms: float(np.sqrt(np.mean([rms[c] ** 2 for c in paired])))
    assert floor(gap["base_fit_holdout_rms"]) < 0.95 * floor(single.holdout_rms)
    other = tmp_path / "other_campaign"                 # the twin's repeat, as if another seed's campaign
    shutil.copytree(out / "twin_reference_1", other)
    meta = json.loads((other / "metadata.json").read_text())
    meta["settings"]["seed"] += 1
    (other / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(PairingError, match="not a run of the data.s campaign"):
        diagnose_paths(run / "identification.json", run, reference_dir=out / "twin_reference",
                       reference_repeats=[other], simulate=False)
    refused = subprocess.run([sys.executable, "-m", "qomni.cli", "diagnose", "--model",
                              str(run / "identification.json"), "--data", str(run), "--out", str(tmp_path / "r"),
                              "--reference", str(out / "twin_reference"), "--twin-runs", "2"],
                             capture_output=True, text=True)
    assert refused.returncode != 0 and "Traceback" not in refused.stderr
    assert "--twin-runs" in refused.stdout + refused.stderr


@pytest.mark.slow
def test_an_effect_the_identification_absorbs_in_part_is_named_against_the_runs_own_twin(suite):
    """A torque-constant error on one drive biases the same-run identification; with the model's base
    parameters free (it was identified on these data) the diagnosis against its twin names the drive.
    A weaker fl and a stronger rl load the left side's rows alike once the base is free: the diagnosis
    names one and gives the other as an equivalent explanation; the weaker fl must be among them.
    It is named first. The left steering step suggests wheel-joint Stribeck friction as a further effect
    (p = 3·10⁻⁴ against its bar of 6·10⁻⁴); the lifted breakaway test withdraws it (docs/diagnosis.md,
    Limits)."""
    work, _ = suite
    gap = diagnose_against_own_twin(work / "torque", work / "torque" / "twin_gap")
    assert gap["model_identified_on_data"] is True
    assert gap["accepted"][0]["name"] == "torque_constant_error", gap["verdict"]
    assert all(a["name"] != "torque_constant_error" for a in gap["accepted"][1:]), gap["verdict"]
    first = gap["accepted"][0]
    named = {first["variant"]: first, **{e["variant"]: e for e in first["equivalent"]}}
    assert set(named) <= {"drive fl", "drive rl"}, gap["verdict"]
    fl = named["drive fl"]
    assert fl["ci"][0] <= fl["magnitude"] <= fl["ci"][1] and fl["ci"][1] < 0   # 0.88: a weaker drive
    assert fl["ci"][0] < -0.12 < fl["ci"][1]
    assert "torque_constant_error (drive fl)" in gap["verdict"]
    # forward selection's record: each round beside the effects before it, nothing named that failed a test
    rounds = gap["selection"]
    assert rounds and rounds[0]["beside"] == [first["name"] + " (" + first["variant"] + ")"]
    assert all(not (t["named"] and t["failed"]) for r in rounds for t in r["tested"])
    assert all([t["effect"] for t in r["tested"] if t["named"]] == ([r["named"]] if r["named"] else [])
               for r in rounds)
    assert all(set(t["gates"]) == {"p_below_level", "present", "physical", "shares_above_0", "affected_channel"}
               for r in rounds for t in r["tested"])


def test_a_hypothesis_to_withhold_must_be_in_the_library():
    from qomni.diagnosis.diagnose import diagnose

    with pytest.raises(ValueError, match="no_such_effect"):
        diagnose(None, "nowhere", withhold=("no_such_effect",))


@pytest.mark.slow
def test_an_effect_whose_hypothesis_is_withheld_is_not_named(suite):
    """``withhold`` leaves a hypothesis out of the library, every variant: the torque-constant case against
    its own twin then names no torque-constant error and ranks none (what it says instead is measured by
    ``benchmarks/blind_suite.py --withhold``, docs/results.md)."""
    from qomni.diagnosis.diagnose import diagnose_paths
    from qomni.twin import twin_reference

    work, _ = suite
    run = work / "torque"
    ref = twin_reference(run / "identification.json", run, run / "twin_gap" / "twin_reference")
    d = diagnose_paths(run / "identification.json", run, reference_dir=ref, simulate=False,
                       withhold=("torque_constant_error",))
    assert all(c.hypothesis.name != "torque_constant_error" for c in d.candidates)
    assert "torque_constant_error" not in d.verdict
    assert d.candidates, "the other hypotheses are still tested"
