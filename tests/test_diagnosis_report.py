"""The diagnosis report (report.html): its sections, the named effect's overlay, gap.json's intervals in
the page, side-by-side reference, atomic writing and escaping of user text. Built from a small synthetic
diagnosis (real result classes, made-up numbers) so that it runs in about a second."""
from __future__ import annotations

import base64
import html
import json
import re
from types import SimpleNamespace

import numpy as np
import pytest

from qomni.diagnosis.channels import ChannelData
from qomni.diagnosis.diagnose import Diagnosis, _tested_json, further_gates
from qomni.diagnosis.evaluation import ChannelShrink, Evaluation
from qomni.diagnosis.fit import Candidate
from qomni.diagnosis.hypotheses.base import Hypothesis, Magnitude
from qomni.diagnosis.problem import Fit
from qomni.diagnosis.report import GAP_JSON, REPORT_HTML, unnamed_further, write_report
from qomni.diagnosis.where import breakdown

HOSTILE = "<script>alert('x')</script>&"


def _channel(name: str, step: str, residual: np.ndarray, offset: float) -> ChannelData:
    n = len(residual)
    t = np.arange(n) * 0.004
    st = SimpleNamespace(time=t, cycle_time=0.004, q=np.zeros((n, 5)),
                         motor_torque=np.zeros((n, 4)))
    ctx = SimpleNamespace(st=st, keep=np.ones(n, bool), step=step, k=3,
                          traction_limited=np.zeros(n, bool), lifted=False)
    v = np.sin(2 * np.pi * 0.5 * t) + offset
    y = residual + 2.0 * v
    return ChannelData(name, "torque", "N m", 0, y, np.zeros((n, 10)), 2.0 * v, v,
                       np.gradient(v, t), np.abs(v) > 0.05, ctx)


def _evaluation(affected: str, before: float, after: float, ci) -> Evaluation:
    return Evaluation([ChannelShrink(affected, before, after), ChannelShrink("other", 1.0, 1.0)],
                      10.0, 4.0, affected, 1 - after / before, ci, 0.6, (0.25, 0.9),
                      {"rotation": (0.45, 0.1), "straight": (0.15, 0.12)})


def _candidate(label: str, channel: str, shrink_ci, p: float, significant: bool,
               gain: float) -> Candidate:
    h = Hypothesis(label, f"drive {label}", ("c",), lambda ch, nl: ch.velocity[:, None])
    fit = Fit(h, None, np.array([gain]), np.eye(1), np.zeros(10), {}, 1.0, 100.0, 11)
    ev = _evaluation(channel, 0.5, 0.2, shrink_ci)
    mag = Magnitude(gain, (gain - 0.1, gain + 0.1), "N m s/rad", "viscous coefficient")
    return Candidate(h, fit, mag, p, ev, {"separable": True}, True, significant, [], ev, ev)


@pytest.fixture()
def diagnosis():
    rng = np.random.default_rng(1)
    n = 1500
    t = np.arange(n) * 0.004
    hostile_channel = f"step{HOSTILE}/x_ch"
    chans = [_channel(hostile_channel, f"step{HOSTILE}", 0.3 * np.sin(2 * np.pi * 0.5 * t)
                      + 0.05 * rng.standard_normal(n), 0.0),
             _channel("rotation/theta_ch", "rotation", 0.05 * rng.standard_normal(n), 0.2)]
    ref = [_channel(c.name, c.step, 0.05 * rng.standard_normal(n), 0.0) for c in chans]
    effect = _candidate(f"viscous{HOSTILE}", hostile_channel, (0.41, 0.77), 3e-9, True, 0.3)
    other = _candidate("payload", "rotation/theta_ch", (-0.05, 0.12), 0.4, False, 0.01)
    sim = {hostile_channel: {"before": {"rms": 0.4, "unit": "N m"}, "after": {"rms": 0.1, "unit": "N m"},
                             "shrink": 0.75}}
    ref_sim = {hostile_channel: {"before": {"rms": 0.06, "unit": "N m"},
                                 "after": {"rms": 0.07, "unit": "N m"}, "shrink": -0.17}}
    # a further effect below its round's level whose held-out shares' interval reaches 0, and one above it
    near = _candidate(f"mass{HOSTILE}", "rotation/theta_ch", (0.0, 0.2), 1e-5, False, 0.02)
    near.presence_p = 1e-6
    near.evaluation = Evaluation([ChannelShrink("rotation/theta_ch", 0.5, 0.43)], 10.0, 9.0,
                                 "rotation/theta_ch", 0.25, (0.0, 0.4), 0.3, (-0.2, 0.7),
                                 {"rotation": (0.35, 0.1), f"step{HOSTILE}": (-0.05, 0.3)})
    level = 1e-3
    selection = [{"beside": [effect.hypothesis.label], "level": level, "named": None,
                  "tested": [_tested_json(c, further_gates(c, level, None), "failed") for c in (near, other)]}]
    fp = SimpleNamespace(channels=chans)
    return Diagnosis(breakdown(chans, 10), [effect, other], [effect], f"unmodelled effect: viscous{HOSTILE}",
                     [], sim, "alternate 1 s windows of the data", f"/runs/{HOSTILE}/identification.json",
                     f"/runs/{HOSTILE}", {}, None, None, chans, (fp, fp), None, None,
                     {hostile_channel: 0.22, "rotation/theta_ch": 0.05},
                     {hostile_channel: 0.5, "rotation/theta_ch": 0.05},
                     {"status": "complete", "steps_used": ["rotation"],
                      "spikes": {"repaired": True, "total_corrupt": 3}}, f"/twin/{HOSTILE}",
                     ref, breakdown(ref, 10),
                     {"model": {hostile_channel: 0.05, "rotation/theta_ch": 0.05},
                      "with_effects": {hostile_channel: 0.07, "rotation/theta_ch": 0.05}}, ref_sim,
                     selection=selection)


def test_report_sections_overlay_intervals_and_escaping(diagnosis, tmp_path):
    out = tmp_path / f"out{HOSTILE}"
    json_path, html_path = write_report(diagnosis, out)
    page = html_path.read_text()
    gap = json.loads(json_path.read_text())
    # Every section, and the reference named beside the data.
    for heading in ("Where: the residual over the campaign", "Which: hypotheses",
                    "How far: held-out residual", "How far: forward simulation"):
        assert f"<h2>{heading}" in page
    assert "Reference: " + html.escape(f"/twin/{HOSTILE}") in page
    assert gap["reference"] == f"/twin/{HOSTILE}" and gap["reference_kind"] == "recorded run"   # no twin stamp
    assert "3 isolated glitches repaired before the fit" in page and gap["data_run"]["spikes"]["total_corrupt"] == 3
    # The verdict and the overlaid effect are the accepted one; one residual figure per step.
    assert "Verdict: " + html.escape(f"unmodelled effect: viscous{HOSTILE}") in page
    assert html.escape(diagnosis.accepted[0].hypothesis.label + " (predicted)") in page
    assert page.count(": residual over the step</figcaption>") == 2
    # Intervals of gap.json: the effect's magnitude CI and its held-out shrink bootstrap CI.
    e = gap["effects"][0]
    assert f"[{e['ci'][0]:.4g}, {e['ci'][1]:.4g}]" in page
    lo, hi = e["holdout_shrink_ci"]
    assert f"[{100 * lo:.1f}, {100 * hi:.1f}]" in page
    # each coefficient with its interval, θ ± 1.96 σ (the fixture's fit has unit covariance)
    c = e["coefficients"]["c"]
    assert e["coefficients_ci"] == {"c": [pytest.approx(c - 1.96), pytest.approx(c + 1.96)]}
    assert f"c {c:.4g} [{c - 1.96:.4g}, {c + 1.96:.4g}]" in page
    assert e["holdout_removed"] == 6.0
    assert e["holdout_removed_share"] == 0.6 and e["holdout_removed_share_ci"] == [0.25, 0.9]
    assert e["holdout_removed_share_by_step"] == {"rotation": {"share": 0.45, "sd": 0.1},
                                                 "straight": {"share": 0.15, "sd": 0.12}}
    # Forward selection: why a further effect below its level was not named, and where its held-out
    # shares' width came from; one above its level is recorded in gap.json but not listed on the page.
    near, other = gap["selection"][0]["tested"]
    accepted = gap["accepted"][0]
    assert gap["selection"][0]["beside"] == [f"{accepted['name']} ({accepted['variant']})"]
    assert gap["selection"][0]["named"] is None
    assert near["failed"] == ["shares_above_0"] and near["holdout_removed_share_ci"] == [-0.2, 0.7]
    assert near["holdout_removed_share_by_step"]["rotation"] == {"share": 0.35, "sd": 0.1}
    assert near["affected_channel"] == "rotation/theta_ch" and near["holdout_shrink_ci"] == [0.0, 0.4]
    assert "rotation/theta_ch: 25.0 % [0.0, 40.0]" in page.split("Further effects that reached")[1]
    assert other["failed"] == ["p_below_level", "present"] and not other["named"] and other["outcome"] == "failed"
    assert "held-out shares&#x27; interval reaches 0" in page and html.escape(f"mass{HOSTILE}") in page
    assert html.escape(f"step{HOSTILE}") + " -0.05 (sd 0.30)" in page and "payload" not in page.split(
        "Further effects that reached")[1].split("</table>")[0]
    # what the CLI prints beside the verdict: the last round's effects below its level and not named
    assert unnamed_further(gap["selection"]) == [(near["effect"], 1e-5, 1e-3,
                                                ["held-out shares' interval reaches 0"])]
    assert unnamed_further([]) == []
    assert "whiteness or input-correlation test: data: " in page and "; reference (twin): " in page
    assert gap["reference_holdout_rms"]["with_effects"] and gap["reference_simulation"]
    # Figures are embedded, valid PNGs; no file beside the page but the two outputs.
    pngs = re.findall(r"data:image/png;base64,([A-Za-z0-9+/=]+)", page)
    assert len(pngs) >= 6
    assert all(base64.b64decode(p).startswith(b"\x89PNG") for p in pngs)
    assert sorted(p.name for p in out.iterdir()) == sorted([GAP_JSON, REPORT_HTML])
    # No user text reaches the page unescaped.
    assert "<script>" not in page and HOSTILE not in page


def test_report_without_reference_or_effect(diagnosis, tmp_path):
    """No reference run, nothing accepted: the page says so; the top-ranked hypothesis is overlaid marked
    as not accepted, and no reference column is drawn."""
    d = diagnosis
    d.accepted, d.verdict, d.reference = [], "no significant unmodelled effect", "none"
    d.reference_channels, d.reference_where, d.reference_holdout_rms, d.reference_simulation = [], {}, {}, {}
    d.candidates[0].significant = False
    page = write_report(d, tmp_path)[1].read_text()
    assert "Reference: none" in page
    assert "(top ranked, not accepted)" in page
    assert "reference (twin), same scale" not in page


def test_reference_holdout_is_the_reference_runs_residual(diagnosis):
    """The reference run's RMS under the model is its residual's RMS over its fitted rows (torque
    channels: no nuisance terms), and adding an effect at a level changes it by that effect's columns."""
    from qomni.diagnosis.diagnose import _reference_holdout
    from qomni.diagnosis.problem import make_problem

    ref = diagnosis.reference_channels
    fp, _ = make_problem(ref, 10, ref)
    fit = diagnosis.accepted[0].fit
    out = _reference_holdout(fp, [fit], 10)
    for ch in ref:
        r = ch.residual[ch.fitted]
        assert out["model"][ch.name] == pytest.approx(np.sqrt(np.mean(r ** 2)))
        after = r - fit.theta[0] * ch.velocity[ch.fitted]
        assert out["with_effects"][ch.name] == pytest.approx(np.sqrt(np.mean(after ** 2)))
    assert _reference_holdout(None, [fit], 10) == {}


def test_equivalent_explanations_are_the_significant_ones_inside_the_accepted_interval():
    """An accepted effect's equivalents: significant, not accepted, held-out shrink inside its interval."""
    from qomni.diagnosis.diagnose import equivalents

    def cand(label, shrink, ci, significant=True):
        return SimpleNamespace(hypothesis=SimpleNamespace(label=label), significant=significant,
                               evaluation=SimpleNamespace(shrink_affected=shrink, shrink_affected_ci=ci))

    rl = cand("tce rl", 0.80, (0.68, 0.89))
    fl = cand("tce fl", 0.79, (0.64, 0.88))
    rr = cand("tce rr", 0.41, (-0.01, 0.71))                # its interval overlaps, its estimate does not
    weak = cand("stribeck", 0.75, (0.6, 0.9), significant=False)
    second = cand("incline", 0.78, (0.7, 0.85))             # accepted itself: never an alternative
    refit = cand("incline", 0.77, (0.7, 0.85))              # its joint refit in forward selection
    found = equivalents([rl, fl, second, weak, rr], [rl, refit])
    assert found == {"tce rl": [fl], "incline": [fl]}


def test_a_further_effects_coefficients_are_its_own_not_the_accepted_ones():
    # forward selection fits a further effect jointly with the accepted ones: θ = (accepted…, own…)
    from qomni.diagnosis.report import candidate_json
    further = _candidate("payload", "lane_change/x_ch", (0.75, 0.86), 2e-31, True, 0.0)
    further.hypothesis = Hypothesis("payload", "", ("m_x_c", "m_y_c"), lambda ch, nl: None)
    further.fit = Fit(further.fit.hypothesis, None, np.array([0.0059, -0.0136, 0.0178, 33.2, 33.7]), np.eye(5),
                      np.zeros(10), {}, 1.0, 100.0, 15)
    assert candidate_json(further, 3)["coefficients"] == {"m_x_c": 33.2, "m_y_c": 33.7}
    # each with its own 95 % interval from the joint covariance's tail
    cov = np.diag([1.0, 1.0, 1.0, 25.0, 0.25])
    further.fit = Fit(further.fit.hypothesis, None, further.fit.theta, cov, np.zeros(10), {}, 1.0, 100.0, 15)
    ci = candidate_json(further, 3)["coefficients_ci"]
    assert ci["m_x_c"] == pytest.approx([33.2 - 9.8, 33.2 + 9.8])
    assert ci["m_y_c"] == pytest.approx([33.7 - 0.98, 33.7 + 0.98])
