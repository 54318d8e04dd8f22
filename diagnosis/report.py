"""``gap.json`` and the HTML report of a diagnosis (plots embedded as PNG)."""
from __future__ import annotations

import html
import math
import os
from pathlib import Path

import numpy as np

from qomni.ident.rundir import TWIN_STAMP, read_json, write_json

from .diagnose import Diagnosis
from .figures import unit_text
from .fit import PRIOR_STD_FACTOR, Candidate

GAP_JSON = "gap.json"
REPORT_HTML = "report.html"
AUGMENTED_JSON = "augmented_identification.json"


def augmented_identification(d: Diagnosis) -> dict | None:
    """The model with the diagnosis folded in, in ``identification.json`` form (``qomni export-fmu``
    exports it): the base parameters' shift δp of the final fit, plus the accepted effects that the
    paper's parameters can carry (``Hypothesis.folds_into``: a payload's Δm_ch, ΔC_ch; rolling
    resistance as Δd_cw = c_rr·m_ch·g·r/4). The others are listed under ``not_representable``."""
    if d.model is None or d.final_fit is None:
        return None
    from qomni.conventions import P1_NAMES
    from .diagnose import fold

    r = d.channels[0].context.sheet.geometry.r if d.channels else 0.1
    p, rest = fold(d.model, d.final_fit, d.accepted, r)
    data = d.model.to_json_dict()
    for k, n in enumerate(P1_NAMES):
        data["parameters"][n]["value"] = float(p[k])
    data["augmented_by"] = {"diagnosis": d.verdict,
                            "folded": [c.hypothesis.name for c in d.accepted if c not in rest],
                            "not_representable": [c.hypothesis.label for c in rest],
                            "base_shift": "δp of the final diagnosis fit (within the model's prior)"}
    return data


def _finite(x):
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        return _finite(x.item())
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def _base_parameters(d: Diagnosis) -> str:
    """How the fits treat the base parameters, in words (gap.json ``base_parameters``)."""
    if not d.model_from_data:
        return f"held within their prior ({PRIOR_STD_FACTOR:g} sigma of the model's)"
    text = "free (the model was identified on these data)"
    if d.lifted:
        text += (", except " + ", ".join(d.lifted) + f": held within {PRIOR_STD_FACTOR:g} sigma of their value "
                 "measured on the lifted vehicle (single_axis.json)")
    return text


def candidate_json(c: Candidate, rank: int) -> dict:
    m = c.magnitude
    ev = c.from_model
    return {
        "rank": rank,
        "name": c.hypothesis.name,
        "variant": c.hypothesis.variant,
        "magnitude": m.value,
        "unit": m.unit,
        "quantity": m.quantity,
        "ci": list(m.ci),
        "significant": c.significant,
        "p_value": c.p_value,
        "presence_p_value": c.presence_p,
        "holdout_shrink": ev.shrink_affected,
        "holdout_shrink_ci": list(ev.shrink_affected_ci),
        "holdout_shrink_beyond_base_fit": c.shrink.shrink_affected,
        "holdout_shrink_beyond_base_fit_ci": list(c.shrink.shrink_affected_ci),
        "holdout_shrink_beyond_reference": c.evaluation.shrink_affected,
        "holdout_shrink_beyond_reference_ci": list(c.evaluation.shrink_affected_ci),
        "affected_channel": ev.affected,
        "holdout_removed": c.evaluation.removed,
        "holdout_removed_share": c.evaluation.removed_share,
        "holdout_removed_share_ci": (None if c.evaluation.removed_share_ci is None
                                     else list(c.evaluation.removed_share_ci)),
        "holdout_removed_share_by_step": c.evaluation.removed_share_by_step_json() or None,
        "holdout_channels": {s.name: {"rms_before": s.rms_before, "rms_after": s.rms_after,
                                      "shrink": s.shrink} for s in ev.channels},
        "nonlinear_parameter": None if c.fit.nonlinear is None else
        {"value": c.fit.nonlinear, "unit": c.hypothesis.nonlinear_unit},
        "coefficients": c.coefficients,
        "coefficients_ci": c.coefficients_ci,
        "identifiability": c.identifiability,
        "physical": c.physical,
        "notes": c.notes,
        "measured_by": c.measured or None,
    }


def reference_kind(reference: str) -> str:
    """``"digital twin"`` (a run ``qomni.twin`` made and stamped), ``"recorded run"`` (one given by the
    user, e.g. the run a model was identified on) or ``"none"``."""
    if reference == "none":
        return "none"
    return "digital twin" if (Path(reference) / TWIN_STAMP).is_file() else "recorded run"


def reference_parameters(reference: str) -> str | None:
    """What a digital twin reference run was made from (its ``twin.json``: the model as identified, or a
    physically consistent re-identification of the data run); None for another reference run."""
    stamp = Path(reference) / TWIN_STAMP
    if reference == "none" or not stamp.is_file():
        return None
    return read_json(stamp).get("parameters", "the model as identified")


def _equivalent_json(o: Candidate) -> dict:
    """An equivalent explanation of an accepted effect (:func:`.diagnose.equivalents`) in ``gap.json``."""
    return {"label": o.hypothesis.label, "name": o.hypothesis.name, "variant": o.hypothesis.variant,
            "magnitude": o.magnitude.value, "ci": list(o.magnitude.ci),
            "holdout_shrink_beyond_reference": o.evaluation.shrink_affected,
            "holdout_shrink_beyond_reference_ci": list(o.evaluation.shrink_affected_ci)}


def gap_dict(d: Diagnosis) -> dict:
    """The content of ``gap.json``: ``effects`` ranked (all candidates, most held-out residual
    removed first; the accepted ones carry ``significant: true``), ``verdict``, ``accepted``,
    ``where`` and ``simulation``; with a reference run, ``reference_holdout_rms`` (``model`` and
    ``with_effects``: channel → RMS on the reference run, every row held out, like ``model_holdout_rms``)
    and ``reference_simulation`` (as ``simulation``). ``selection``: forward selection's rounds after the
    first effect, each hypothesis tested as a further effect with the tests of its gate that it
    ``failed`` (``Diagnosis.selection``).

    An effect's ``holdout_shrink`` is 1 − RMS(after)/RMS(before) on held-out rows of its
    ``affected_channel``: before, the model as identified (with the effects accepted before it);
    after, the same model with the effect added at its fitted level (``model_holdout_rms`` holds the
    model's RMS per channel). ``holdout_shrink_beyond_base_fit`` starts from the base fit instead, whose
    base parameters may move within their prior and so absorb part of an effect collinear with them
    (``base_fit_holdout_rms``); ``holdout_shrink_beyond_reference`` from the reference run's level of
    the hypothesis (what the significance gate uses). An accepted effect's ``equivalent`` lists the
    significant candidates that explain the data as well (held-out shrink beyond the reference inside
    the accepted effect's interval) and add nothing beyond the accepted effects: the campaign cannot
    tell them apart."""
    ranked = [candidate_json(c, i + 1) for i, c in enumerate(d.candidates)]
    return _finite({
        "verdict": d.verdict,
        "accepted": [{**candidate_json(c, i + 1),
                      "equivalent": [_equivalent_json(o) for o in d.equivalent.get(c.hypothesis.label, [])]}
                     for i, c in enumerate(d.accepted)],
        "effects": ranked,
        "selection": d.selection,
        "structured_channels": d.structured,
        "holdout": d.holdout,
        "model": d.model_source,
        "data": d.data_source,
        "data_run": d.data_run,
        "reference": d.reference,
        "reference_kind": reference_kind(d.reference),
        "reference_parameters": reference_parameters(d.reference),
        "paired_channels": d.paired_channels,
        "reference_repeats": d.reference_repeats,
        "model_identified_on_data": d.model_from_data,
        "base_parameters": _base_parameters(d),
        "lifted_wheel_friction": {n: {"value": v, "std": s} for n, (v, s) in d.lifted.items()},
        "base_parameter_shift": d.base_delta_p,
        "model_holdout_rms": d.model_holdout_rms,
        "base_fit_holdout_rms": d.holdout_rms,
        "where": d.where,
        "simulation": d.simulation,
        "reference_holdout_rms": d.reference_holdout_rms,
        "reference_simulation": d.reference_simulation,
    })


def _write_text(path: Path, text: str) -> None:
    """Write ``text`` atomically (a temporary file beside ``path``, then renamed over it)."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def _fmt(x, spec: str = ".4g") -> str:
    return "–" if x is None or x != x else format(x, spec)


def _img(title: str, data: str) -> str:
    return f"<figure><img alt='{html.escape(title, quote=True)}' src='data:image/png;base64,{data}'/>" \
           f"<figcaption>{html.escape(title)}</figcaption></figure>"


def _which_table(gap: dict) -> str:
    rows = "".join(
        f"<tr class='{'acc' if e['significant'] else ''}'><td>{e['rank']}</td><td>{html.escape(e['name'])}</td>"
        f"<td>{html.escape(e['variant'])}</td><td>{_fmt(e['magnitude'])} {html.escape(unit_text(e['unit']))}</td>"
        f"<td>[{_fmt(e['ci'][0])}, {_fmt(e['ci'][1])}]</td><td>{_coefficients(e)}</td>"
        f"<td>{_fmt(e['p_value'], '.2g')}</td>"
        f"<td>{_fmt(e.get('presence_p_value'), '.2g')}</td>"
        f"<td>{_fmt(100 * e['holdout_shrink'], '.1f')} %{_percent_interval(e['holdout_shrink_ci'])} "
        f"({html.escape(e['affected_channel'])})</td>"
        f"<td>{'yes' if e['significant'] else 'no'}</td>"
        f"<td>{'yes' if e['identifiability']['separable'] else 'no'}</td></tr>"
        for e in gap["effects"] if e["magnitude"] is not None)
    return ("<table><tr><th>#</th><th>effect</th><th>variant</th><th>magnitude</th><th>95 % CI</th>"
            "<th>coefficients [95 % CI]</th><th>p (beyond reference)</th>"
            "<th>p (level zero)</th>"
            f"<th>held-out shrink [95 % CI] (channel)</th><th>significant</th><th>separable</th></tr>{rows}</table>")


def _coefficients(effect: dict) -> str:
    """An effect's own coefficients, each with its 95 % interval where ``gap.json`` records it."""
    ci = effect.get("coefficients_ci") or {}
    return "; ".join(html.escape(name) + " " + _fmt(value)
                     + (f" [{_fmt(ci[name][0])}, {_fmt(ci[name][1])}]" if name in ci else "")
                     for name, value in (effect.get("coefficients") or {}).items())


#: A further effect's gate tests (``diagnose.further_gates``) as the report and the CLI word a failure.
GATE_FAILED = {"p_below_level": "p above the level", "present": "level not distinct from zero",
               "physical": "not physical", "shares_above_0": "held-out shares' interval reaches 0",
               "affected_channel": "too little removed in its channel"}


def unnamed_further(selection: list[dict]) -> list[tuple[str, float, float, list[str]]]:
    """The further effects of selection's last round (the model as it ends) that reached the round's level
    and were not named: (effect, p, level, the failed tests worded as :data:`GATE_FAILED`)."""
    if not selection:
        return []
    last = selection[-1]
    return [(t["effect"], t["p_value"], last["level"], _why_not(t))
            for t in last["tested"] if t["gates"]["p_below_level"] and not t["named"]]


def _why_not(tested: dict) -> list[str]:
    """A further effect's failed tests worded as :data:`GATE_FAILED`, or its outcome where it passed."""
    return [GATE_FAILED.get(g, g) for g in tested["failed"]] or [tested["outcome"]]


def _selection_table(gap: dict) -> str:
    """Forward selection's rounds: per round the further effects that reached the round's level or were
    named, with the tests of the gate they failed and where their held-out shares came from."""
    rows = []
    for i, rnd in enumerate(gap.get("selection") or []):
        for t in rnd["tested"]:
            if not (t["named"] or t["gates"]["p_below_level"]):
                continue
            ci = t["holdout_removed_share_ci"] or [None, None]
            steps = ", ".join(f"{html.escape(step)} {_fmt(v['share'], '+.2f')} (sd {_fmt(v['sd'], '.2f')})"
                              for step, v in t["holdout_removed_share_by_step"].items()
                              if abs(v["share"]) >= 0.005 or v["sd"] >= 0.005)
            verdict = "named" if t["named"] else "; ".join(_why_not(t))
            rows.append(f"<tr class='{'acc' if t['named'] else ''}'><td>{i + 2}</td>"
                        f"<td>{html.escape(', '.join(rnd['beside']))}</td><td>{html.escape(t['effect'])}</td>"
                        f"<td>{_fmt(t['p_value'], '.2g')} ({_fmt(rnd['level'], '.2g')})</td>"
                        f"<td>{_fmt(t['holdout_removed_share'], '.2f')} [{_fmt(ci[0], '.2f')}, "
                        f"{_fmt(ci[1], '.2f')}]</td><td>{_affected_shrink(t)}</td><td>{steps}</td>"
                        f"<td>{html.escape(verdict)}</td></tr>")
    if not rows:
        return ""
    return ("<p>Further effects that reached their round's level, with the effects already in the model: "
            "named, or the test of the gate they failed.</p><table><tr><th>round</th><th>beside</th>"
            "<th>effect</th><th>p (level)</th><th>held-out shares removed [95 % CI]</th>"
            "<th>affected channel: held-out shrink [95 % CI]</th>"
            f"<th>by step: share (sd)</th><th>outcome</th></tr>{''.join(rows)}</table>")


def _affected_shrink(tested: dict) -> str:
    """A further effect's affected channel and its held-out shrink in %, with its interval where
    ``gap.json`` records one."""
    return (f"{html.escape(tested['affected_channel'])}: {_fmt(100 * tested['holdout_shrink'], '.1f')} %"
            f"{_percent_interval(tested.get('holdout_shrink_ci'))}")


def _percent_interval(ci) -> str:
    """A held-out shrink's interval (fractions) as " [lo, hi]" in %, or "" where there is none."""
    return f" [{_fmt(100 * ci[0], '.1f')}, {_fmt(100 * ci[1], '.1f')}]" if ci else ""


def _holdout_table(gap: dict) -> str:
    after = gap["accepted"][-1]["holdout_channels"] if gap["accepted"] else {}
    ci = {e["affected_channel"]: e["holdout_shrink_ci"] for e in gap["accepted"]}
    ref = gap.get("reference_holdout_rms") or {}
    ref_model, ref_after = ref.get("model", {}), ref.get("with_effects", {})
    rows = ""
    for n, before in gap["model_holdout_rms"].items():
        a = after.get(n, {}).get("rms_after")
        shrink = None if a is None or not before else 1 - a / before
        rows += (f"<tr><td>{html.escape(n)}</td><td>{_fmt(before)}</td><td>{_fmt(a)}</td>"
                 f"<td>{'–' if shrink is None else _fmt(100 * shrink, '.1f') + ' %'}{_percent_interval(ci.get(n))}</td>"
                 f"<td>{_fmt(ref_model.get(n))}</td><td>{_fmt(ref_after.get(n))}</td></tr>")
    return ("<table><tr><th>channel</th><th>data: model</th><th>data: + accepted effects</th>"
            "<th>shrink [95 % bootstrap CI]</th><th>reference (twin): model</th>"
            "<th>reference: + accepted effects</th></tr>"
            f"{rows}</table><p class='note'>Held-out RMS residual in each channel's unit. The reference "
            "columns are what the model leaves on its own twin's run (every row held out), without and with "
            "the accepted effects at the levels fitted to the data.</p>")


def _simulation_table(sim: dict, ref: dict) -> str:
    rows = ""
    for n, s in sim.items():
        if s["before"]["rms"] != s["before"]["rms"]:
            continue
        r = ref.get(n)
        rows += (f"<tr><td>{html.escape(n)}</td><td>{_fmt(s['before']['rms'])}</td><td>{_fmt(s['after']['rms'])}</td>"
                 f"<td>{_fmt(100 * s['shrink'], '.1f')} %</td>"
                 f"<td>{_fmt(r['before']['rms']) if r else '–'}</td><td>{_fmt(r['after']['rms']) if r else '–'}</td>"
                 f"<td>{html.escape(s['before']['unit'])}</td></tr>")
    return ("<table><tr><th>channel</th><th>data: before</th><th>data: after</th><th>shrink</th>"
            "<th>reference: before</th><th>reference: after</th><th>unit</th></tr>"
            f"{rows}</table>")


def _structure_line(d: Diagnosis) -> str:
    from .where import structured
    tested = structured(d.where)
    line = ("Channels whose residual under the model fails the whiteness or input-correlation test: data: "
            + html.escape(", ".join(tested) or "none"))
    if d.reference_where:
        on_ref = set(structured(d.reference_where))
        line += ("; reference (twin): " + html.escape(", ".join(n for n in d.reference_where if n in on_ref)
                                                       or "none")
                 + " (structure the twin shows as well is the model's own, not an unmodelled effect)")
    line += "."
    if d.accepted:
        line += " The accepted effects are tested on held-out data below (How far)."
    elif d.structured:
        line += " Structure no named effect explains: " + html.escape(", ".join(d.structured)) + "."
    return line


STYLE = """body{font-family:sans-serif;max-width:1150px;margin:auto;color:#222}
td,th{padding:2px 8px;text-align:right;border-bottom:1px solid #ddd}td:nth-child(-n+3){text-align:left}
table{border-collapse:collapse;font-size:90%}tr.acc{background:#e8f5e9}.verdict{font-size:130%;padding:8px;
background:#f3f3f3;border-left:6px solid #2e7d32}figure{margin:10px 0}img{max-width:100%}
figcaption,.note{font-size:85%;color:#555}"""


def report_html(d: Diagnosis, gap: dict) -> str:
    """The HTML page of a diagnosis: headline (verdict, data, reference), Where, Which, How far. User
    text (paths, channel and effect names) is escaped; figures are embedded PNGs."""
    from . import figures

    where_figs = figures.residual_series(d)
    extra = figures.regimes_and_bands(d)
    which = figures.forest(d)
    hold = figures.holdout_bars(d)
    sim = figures.simulation_bars(d)
    _, overlay = figures.overlay_effects(d)
    ref = d.reference if d.reference != "none" else "none (each hypothesis tested against zero)"
    if d.reference_repeats:
        ref += (f", with {len(d.reference_repeats)} further run(s) of its campaign: paired channels diagnosed "
                f"beyond the mean residual of all {len(d.reference_repeats) + 1}")
    status = gap["data_run"].get("status", "not recorded") if gap.get("data_run") else "not recorded"
    spikes = (gap.get("data_run") or {}).get("spikes") or {}
    glitches = (f"; {spikes['total_corrupt']} isolated glitches "
                f"{'repaired' if spikes.get('repaired') else 'kept'} before the fit"
                if spikes.get("total_corrupt") else "")
    return f"""<!DOCTYPE html><html><head><meta charset="utf-8"><title>Sim-to-real gap</title>
<style>{STYLE}</style></head><body>
<h1>Sim-to-real gap diagnosis</h1>
<p class="verdict"><b>Verdict: {html.escape(d.verdict)}</b></p>
<p>Model: {html.escape(d.model_source)}<br>Data: {html.escape(d.data_source)} (run status:
{html.escape(str(status))}{html.escape(glitches)})<br>Reference: {html.escape(ref)}<br>Held out: {html.escape(d.holdout)}</p>
<h2>Where: the residual over the campaign</h2>
<p>Each channel's residual (measured − model) per campaign step; red: {html.escape(overlay or "no effect")};
right: the same channel on the reference run, same scale.</p>
<p>{_structure_line(d)}</p>
{"".join(_img(t, p) for t, p in where_figs)}
{_img(*extra) if extra else ""}
<h2>Which: hypotheses</h2>
{_img(*which) if which else ""}
{_which_table(gap)}
{_selection_table(gap)}
<h2>How far: held-out residual</h2>
{_img(*hold) if hold else ""}
{_holdout_table(gap)}
<h2>How far: forward simulation (1 s windows from the measured state)</h2>
{_img(*sim) if sim else ""}
{_simulation_table(d.simulation, d.reference_simulation)}
</body></html>"""


def write_report(d: Diagnosis, out: str | Path) -> tuple[Path, Path]:
    """Write ``gap.json`` and ``report.html`` into ``out`` (created), each atomically. Returns both
    paths."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    gap = gap_dict(d)
    json_path = out / GAP_JSON
    write_json(json_path, gap)
    augmented = augmented_identification(d)
    if augmented is not None:
        write_json(out / AUGMENTED_JSON, _finite(augmented))
        if d.data_metadata is not None and d.data_metadata.exists():
            # The data sheet export-fmu needs, so that `qomni export-fmu OUT` works on this directory.
            _write_text(out / "metadata.json", d.data_metadata.read_text())
    html_path = out / REPORT_HTML
    _write_text(html_path, report_html(d, gap))
    return json_path, html_path
