"""The blind suite's cases drawn from a master seed (whole realistic ranges, every direction and instance,
pairs, triples, other vehicles, clean cases), the results file recording the draw, and its resumption;
without campaigns (the worker check runs each case's emulator for a tenth of a second)."""
import collections
import math

import numpy as np
import pytest

from qomni.blind_suite import (MAGNITUDES, PROTOTYPE_OWN, VEHICLES, Case, CaseResult, draw, draw_cases, effect_name,
                               probe_case, range_position, read_results, read_run, run_suite, score)
from qomni.emulator.effects import EffectSet
from qomni.emulator.effects.effect_set import REGISTRY


def test_one_master_seed_gives_one_suite_and_another_a_different_one():
    a, b, c = draw_cases(11), draw_cases(11), draw_cases(12)
    assert [(x.name, x.effects, x.seed) for x in a] == [(x.name, x.effects, x.seed) for x in b]
    assert {x.name for x in a}.isdisjoint({x.name for x in c})
    assert len({x.name for x in a}) == len(a)


def test_the_suite_holds_pairs_triples_other_vehicles_and_clean_cases():
    cases = draw_cases(5, singles=2)
    sizes = collections.Counter(len(c.truth) for c in cases)
    assert sizes[2] >= 10 and sizes[3] >= 3
    assert all(len(set(c.truth)) == len(c.truth) for c in cases)             # distinct effects combined
    assert {c.vehicle for c in cases} == {"", *VEHICLES}
    clean = [c for c in cases if not c.truth]
    assert any(c.prototype and c.tolerated == list(PROTOTYPE_OWN) for c in clean)
    assert any(not c.prototype and not c.vehicle for c in clean)
    assert all(EffectSet.from_dict(c.effects) is not None for c in cases)     # every draw is a valid file


def _within(value, a, b):
    lo, hi = min(a, b), max(a, b)
    return lo - 1e-12 <= value <= hi + 1e-12


@pytest.mark.parametrize("entry", sorted(MAGNITUDES))
def test_draws_span_the_realistic_range_in_every_direction(entry):
    rng = np.random.default_rng(3)
    tables = [draw(entry, rng) for _ in range(200)]
    weak, strong = MAGNITUDES[entry]
    for key, w in weak.items():
        if isinstance(w, (int, float)) and not isinstance(w, bool) and w != strong[key]:
            values = np.array([t[key] for t in tables])
            if entry == "torque_constant_error":
                values = 1 - np.abs(1 - values)
                assert (np.array([t[key] for t in tables]) > 1).any()              # above 1 as well
            if entry == "wheel_radius":
                values = 0.1 - np.abs(0.1 - values)
                assert (np.array([t[key] for t in tables]) > 0.1).any()            # a larger wheel as well
            assert all(_within(v, w, strong[key]) for v in values), key
            span = abs(strong[key] - w)
            assert values.max() - values.min() > 0.7 * span, key                   # the whole range
    if entry == "payload":
        quadrants = {(np.sign(t["com_offset"][0]), np.sign(t["com_offset"][1])) for t in tables}
        assert len(quadrants) == 4
    if entry == "incline":
        headings = np.array([t["uphill_heading"] for t in tables])
        assert (np.cos(headings) > 0.5).any() and (np.cos(headings) < -0.5).any()
        assert (np.abs(np.cos(headings)) >= math.sin(REGISTRY["incline"].LATERAL_EXCLUSION) - 1e-9).all()
    if entry == "torque_constant_error":
        assert {t["drive"] for t in tables} == {"fl", "rl", "fr", "rr"}


def test_the_range_ends_are_valid_effects_files_at_the_declared_ends():
    for entry, (weak, strong) in MAGNITUDES.items():
        ends = REGISTRY[effect_name(entry)].range_ends(entry)
        assert len(ends) >= 2
        for table in ends:
            EffectSet.from_dict({effect_name(entry): table})


@pytest.mark.parametrize("entry", sorted(MAGNITUDES))
def test_a_tables_range_position_is_0_at_the_weak_end_1_at_the_strong_end_in_every_direction(entry):
    """The direction or instance (a payload's quadrant, a factor above 1, a larger wheel) does not move a
    table in its range: every range end is at 0 or 1, the declared weak end at 0, the strong at 1, and a
    draw's position is the mean of its numbers' places on the scale it was drawn on."""
    weak, strong = MAGNITUDES[entry]
    ends = [range_position(entry, t) for t in REGISTRY[effect_name(entry)].range_ends(entry)]
    assert range_position(entry, weak) == 0.0 and range_position(entry, strong) == 1.0
    assert set(np.round(ends, 12)) == {0.0, 1.0}
    rng = np.random.default_rng(4)
    positions = [range_position(entry, draw(entry, rng)) for _ in range(300)]
    assert all(0.0 <= x <= 1.0 for x in positions)
    assert min(positions) < 0.25 and max(positions) > 0.75 and 0.4 < np.mean(positions) < 0.6


def test_range_position_places_each_number_on_its_drawn_scale():
    # torque constant: deviation 0.1 between 0.05 and 0.15 on the factor's log scale, either side of 1
    below = range_position("torque_constant_error", {"drive": "rr", "factor": 0.9})
    above = range_position("torque_constant_error", {"drive": "fl", "factor": 1.1})
    assert below == pytest.approx(above) == pytest.approx(math.log(0.9 / 0.95) / math.log(0.85 / 0.95))
    # payload: the mean over mass, both offsets and height, whatever the quadrant
    table = {"mass": 200.0, "com_offset": [-0.4, 0.05], "height": 0.5}
    assert range_position("payload", table) == pytest.approx((math.log(4) / math.log(8) + 1 + 0 + 1) / 4)
    # beyond an end: clipped
    assert range_position("backlash", {"gap": 0.05}) == 1.0


def test_the_score_says_where_in_the_range_the_missed_cases_lie():
    weak_named = CaseResult(Case("backlash_0_s1", {"backlash": {"gap": 0.002}}, ["backlash"], 1, "drawn", "backlash"),
                            accepted=["backlash"], accepted_variants=[""])
    strong_missed = CaseResult(Case("backlash_1_s2", {"backlash": {"gap": 0.02}}, ["backlash"], 2, "drawn",
                                    "backlash"))
    e = score([weak_named, strong_missed])["per_effect"]["backlash"]
    assert e["named_range_positions"] == [0.0] and e["missed_range_positions"] == [1.0]


def test_a_prototype_naming_its_own_steering_units_is_no_false_positive():
    proto = Case("prototype_s1", {}, [], 1, prototype=True, tolerated=list(PROTOTYPE_OWN))
    ideal = Case("ideal_s2", {}, [], 2)
    results = [CaseResult(proto, accepted=["heavy_steering_units"], accepted_variants=[""]),
               CaseResult(ideal, accepted=["heavy_steering_units"], accepted_variants=[""])]
    assert results[0].top1 and not results[0].false_positives
    assert not results[1].top1 and results[1].false_positives == ["heavy_steering_units"]
    assert score(results)["clean_cases_with_false_positive"] == 1


def test_the_results_file_records_the_master_seed_and_each_draw_and_a_rerun_resumes(tmp_path):
    cases = [c for c in draw_cases(21, singles=1, pairs=1, triples=1, other_vehicle_singles=0, clean=1)
             if len(c.truth) != 1][:3]
    path = tmp_path / "r.json"
    run = {"master_seed": 21, "reference": "twin"}
    first = run_suite(cases[:2], tmp_path, workers=1, results_path=path, runner=probe_case, run=run)
    assert not [r.error for r in first if r.error]
    assert read_run(path) == run
    assert {r.case.name: r.case.effects for r in read_results(path)} == {c.name: c.effects for c in cases[:2]}
    again = run_suite(cases, tmp_path, workers=1, results_path=path, runner=_OnlyNew({cases[2].name}), run=run)
    assert sorted(r.case.name for r in again) == sorted(c.name for c in cases)


def test_a_resume_refuses_another_draws_cases_and_an_edited_record_and_keeps_the_results_file(tmp_path):
    """A resume never drops the cases of another draw (the file rewritten without them) nor scores a record
    edited since (its truth no longer the drawn case's)."""
    import json

    from qomni.ident.rundir import RunDirectoryError

    cases = [c for c in draw_cases(23, singles=1, pairs=1, triples=0, other_vehicle_singles=0, clean=1)
             if len(c.truth) != 1][:2]
    path = tmp_path / "r.json"
    run_suite(cases, tmp_path, workers=1, results_path=path, runner=probe_case)
    written = path.read_text()
    other = [c for c in draw_cases(24, singles=1, pairs=1, triples=0, other_vehicle_singles=0, clean=1)
             if len(c.truth) != 1][:2]
    with pytest.raises(RunDirectoryError, match=r"case '.*' is not a case of this draw"):
        run_suite(other, tmp_path, workers=1, results_path=path, runner=_OnlyNew({c.name for c in other}))
    assert path.read_text() == written
    edited = json.loads(written)
    edited["cases"][0]["case"]["truth"] = ["payload"]
    path.write_text(json.dumps(edited))
    with pytest.raises(RunDirectoryError, match=r"differs from the case drawn under that name"):
        run_suite(cases, tmp_path, workers=1, results_path=path, runner=_OnlyNew(set()))


def test_a_rerun_runs_again_the_cases_that_ended_in_an_error(tmp_path):
    cases = [c for c in draw_cases(22, singles=1, pairs=1, triples=1, other_vehicle_singles=0, clean=1)
             if len(c.truth) != 1][:2]
    path = tmp_path / "r.json"
    first = run_suite(cases, tmp_path, workers=1, results_path=path, runner=_FailFirst(cases[0].name))
    assert [bool(r.error) for r in sorted(first, key=lambda r: r.case.name != cases[0].name)] == [True, False]
    again = run_suite(cases, tmp_path, workers=1, results_path=path, runner=_OnlyNew({cases[0].name}))
    assert sorted(r.case.name for r in again) == sorted(c.name for c in cases)
    assert not any(r.error for r in read_results(path))


def test_a_case_campaign_replaces_what_an_attempt_cut_short_left(tmp_path, monkeypatch):
    """The suite runs a case's campaign only where its directory has no identification: what an interrupted
    attempt left there is replaced (--force), and a failure reports the command's own message."""
    import subprocess
    from types import SimpleNamespace as NS

    from qomni.suite import runner

    seen = []

    def fake_run(cmd, **kw):
        seen.append(cmd)
        return NS(returncode=2, stdout="error: already holds single_axis of an earlier run\n", stderr="")

    monkeypatch.setattr(subprocess, "run", fake_run)
    with pytest.raises(RuntimeError, match="already holds single_axis"):
        runner.run_campaign(tmp_path / "case", {"backlash": {"gap": 0.01}}, 7, quick=True)
    assert "--force" in seen[0] and seen[0][seen[0].index("--seed") + 1] == "7"


def test_an_unknown_reference_mode_is_refused(tmp_path):
    with pytest.raises(ValueError, match="reference"):
        run_suite([], tmp_path, reference="nominal")
    with pytest.raises(ValueError, match="at least one"):
        run_suite([], tmp_path, twin_runs=0)


def test_each_case_is_diagnosed_against_as_many_twin_runs_as_the_suite_asks(tmp_path, monkeypatch):
    """``run_suite(twin_runs=K)`` hands K to every case's campaign-and-diagnosis task."""
    from concurrent.futures import ThreadPoolExecutor

    from qomni.suite import runner

    asked = []

    def task(case, work, reference, quick, twin_runs=1):
        asked.append((case.name, reference, twin_runs))
        return CaseResult(case)

    monkeypatch.setattr(runner, "run_case", task)
    cases = draw_cases(5, singles=1, pairs=0, triples=0, other_vehicle_singles=0, clean=0)[:2]
    with ThreadPoolExecutor(1) as pool:                     # threads: the stand-in task is not pickled
        run_suite(cases, tmp_path, executor=pool, twin_runs=3)
        run_suite(cases[:1], tmp_path / "one", executor=pool)
    assert sorted(asked) == sorted([(c.name, "twin", 3) for c in cases] + [(cases[0].name, "twin", 1)])


class _OnlyNew:
    """A picklable runner that refuses the cases already in the results file."""

    def __init__(self, new):
        self.new = new

    def __call__(self, case, work, reference, quick):
        if case.name not in self.new:
            raise AssertionError(f"{case.name} ran again")
        return probe_case(case, work, reference, quick)


class _FailFirst:
    """A picklable runner whose case ``name`` ends in an error, as a campaign cut short does."""

    def __init__(self, name):
        self.name = name

    def __call__(self, case, work, reference, quick):
        r = probe_case(case, work, reference, quick)
        if case.name == self.name:
            r.error = "RuntimeError: campaign cut short"
        return r


def _benchmark_main():
    import importlib.util
    from pathlib import Path
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "blind_suite.py"
    spec = importlib.util.spec_from_file_location("blind_suite_benchmark", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.main


def test_a_work_directory_keeps_its_suite_and_refuses_to_score_another(tmp_path, capsys):
    from qomni.blind_suite import write_results
    main = _benchmark_main()
    run = {"master_seed": 2027, "reference": "twin", "campaigns": "quick", "singles": 1, "pairs": 10,
           "triples": 3, "effects": None}
    write_results([], tmp_path / "blind_suite.json", run)
    # without options the recorded suite is rescored: its campaign length and draws, not the defaults
    assert main(["--work", str(tmp_path), "--recorded-only"]) == 0
    assert "of master seed 2027" in capsys.readouterr().out
    assert read_run(tmp_path / "blind_suite.json") == run
    for other in (["--campaigns", "full"], ["--singles", "5"], ["--pairs", "4"], ["--triples", "1"],
                  ["--effects", "payload"], ["--master-seed", "3"], ["--twin-runs", "3"]):
        assert main(["--work", str(tmp_path), "--recorded-only", *other]) == 2
        assert "use another --work" in capsys.readouterr().out
        assert read_run(tmp_path / "blind_suite.json") == run
    # the other reference scores the same recordings into its own file, with the same master seed
    assert main(["--work", str(tmp_path), "--recorded-only", "--quick", "--reference", "ideal"]) == 0
    assert read_run(tmp_path / "blind_suite_ideal.json") == {**run, "reference": "ideal"}
    assert read_run(tmp_path / "blind_suite.json") == run
    # the twin's repeats are a twin-reference setting, recorded where there are any
    assert main(["--work", str(tmp_path), "--recorded-only", "--reference", "ideal", "--twin-runs", "2"]) == 2
    assert main(["--work", str(tmp_path / "k3"), "--recorded-only", "--quick", "--master-seed", "2027",
                 "--twin-runs", "3"]) == 0
    assert read_run(tmp_path / "k3" / "blind_suite.json")["twin_runs"] == 3
    text = (tmp_path / "blind_suite.json").read_text()
    (tmp_path / "blind_suite.json").write_text(text[:len(text) // 2])              # a results file cut short
    assert main(["--work", str(tmp_path), "--recorded-only"]) == 2
    assert "not valid JSON" in capsys.readouterr().out
    assert main(["--work", str(tmp_path / "k3"), "--recorded-only"]) == 0         # the recorded 3 is the default
    assert main(["--work", str(tmp_path / "k3"), "--recorded-only", "--twin-runs", "1"]) == 2


def test_a_results_file_without_its_combination_counts_was_drawn_with_the_defaults(tmp_path, capsys):
    from qomni.blind_suite import write_results
    main = _benchmark_main()
    older = {"master_seed": 2027, "reference": "twin", "campaigns": "quick", "singles": 1, "effects": None}
    write_results([], tmp_path / "blind_suite.json", older)
    assert main(["--work", str(tmp_path), "--recorded-only", "--pairs", "11"]) == 2
    assert "use another --work" in capsys.readouterr().out
    assert main(["--work", str(tmp_path), "--recorded-only", "--pairs", "10", "--triples", "3"]) == 0
    assert read_run(tmp_path / "blind_suite.json") == {**older, "pairs": 10, "triples": 3}
    assert main(["--work", str(tmp_path), "--recorded-only", "--pairs", "11"]) == 2
    assert "use another --work" in capsys.readouterr().out
