"""``gap.json`` and the HTML report of a diagnosis (plots embedded as PNG)."""
from __future__ import annotations

import base64
import html
import io
import math
from pathlib import Path

import numpy as np

from qomni.ident.rundir import write_json

from .diagnose import Diagnosis
from .evaluation import predicted_residual
from .fit import Candidate

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
        "holdout_shrink": ev.shrink_affected,
        "holdout_shrink_ci": list(ev.shrink_affected_ci),
        "holdout_shrink_beyond_base_fit": c.shrink.shrink_affected,
        "holdout_shrink_beyond_base_fit_ci": list(c.shrink.shrink_affected_ci),
        "holdout_shrink_beyond_reference": c.evaluation.shrink_affected,
        "affected_channel": ev.affected,
        "holdout_removed": c.evaluation.removed,
        "holdout_channels": {s.name: {"rms_before": s.rms_before, "rms_after": s.rms_after,
                                      "shrink": s.shrink} for s in ev.channels},
        "nonlinear_parameter": None if c.fit.nonlinear is None else
        {"value": c.fit.nonlinear, "unit": c.hypothesis.nonlinear_unit},
        "coefficients": dict(zip(c.hypothesis.parameters, c.fit.theta.tolist())),
        "identifiability": c.identifiability,
        "physical": c.physical,
        "notes": c.notes,
    }


def gap_dict(d: Diagnosis) -> dict:
    """The content of ``gap.json``: ``effects`` ranked (all candidates, most held-out residual
    removed first; the accepted ones carry ``significant: true``), ``verdict``, ``accepted``,
    ``where`` and ``simulation``.

    An effect's ``holdout_shrink`` is 1 − RMS(after)/RMS(before) on held-out rows of its
    ``affected_channel``: before, the model as identified (with the effects accepted before it);
    after, the same model with the effect added at its fitted level (``model_holdout_rms`` holds the
    model's RMS per channel). ``holdout_shrink_beyond_base_fit`` starts from the base fit instead, whose
    base parameters may move within their prior and so absorb part of an effect collinear with them
    (``base_fit_holdout_rms``); ``holdout_shrink_beyond_reference`` from the reference run's level of
    the hypothesis (what the significance gate uses)."""
    ranked = [candidate_json(c, i + 1) for i, c in enumerate(d.candidates)]
    return _finite({
        "verdict": d.verdict,
        "accepted": [candidate_json(c, i + 1) for i, c in enumerate(d.accepted)],
        "effects": ranked,
        "structured_channels": d.structured,
        "holdout": d.holdout,
        "model": d.model_source,
        "data": d.data_source,
        "data_run": d.data_run,
        "reference": d.reference,
        "base_parameter_shift": d.base_delta_p,
        "model_holdout_rms": d.model_holdout_rms,
        "base_fit_holdout_rms": d.holdout_rms,
        "where": d.where,
        "simulation": d.simulation,
    })


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    import matplotlib.pyplot as plt
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def _figures(d: Diagnosis) -> list[tuple[str, str]]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figs = []
    # Where: relative residual per channel.
    names = list(d.where)
    fig, ax = plt.subplots(figsize=(8, 0.35 * len(names) + 1))
    vals = [d.where[n]["nrmse"] if d.where[n]["nrmse"] is not None else 0.0 for n in names]
    colors = ["tab:red" if n in d.structured else "tab:blue" for n in names]
    ax.barh(names, [100 * v for v in vals], color=colors)
    ax.set_xlabel("residual RMS / measured RMS [%] (torque channels; red: structured)")
    ax.invert_yaxis()
    figs.append(("Where: residual per channel", _png(fig)))
    # Regimes heat map.
    regimes = ["near_standstill", "slow", "fast", "low_acceleration", "high_acceleration",
               "small_steering_angle", "large_steering_angle"]
    torque = [n for n in names if d.where[n]["kind"] == "torque"]
    if torque:
        grid = np.array([[d.where[n]["regimes"].get(r, {}).get("rms", np.nan) / max(
            d.where[n]["rms_residual"], 1e-12) for r in regimes] for n in torque])
        fig, ax = plt.subplots(figsize=(9, 0.4 * len(torque) + 1.5))
        im = ax.imshow(grid, aspect="auto", cmap="viridis")
        ax.set_xticks(range(len(regimes)), regimes, rotation=30, ha="right")
        ax.set_yticks(range(len(torque)), torque)
        fig.colorbar(im, label="RMS residual / channel RMS residual")
        figs.append(("Where: operating regimes", _png(fig)))
    # Which: ranking.
    top = d.candidates[:12]
    fig, ax = plt.subplots(figsize=(8, 0.35 * len(top) + 1))
    ax.barh([c.hypothesis.label for c in top], [100 * c.from_model.shrink_affected for c in top],
            color=["tab:green" if c.significant else "tab:gray" for c in top])
    ax.set_xlabel("held-out residual removed in the affected channel [%] (green: significant)")
    ax.invert_yaxis()
    figs.append(("Which: hypotheses ranked by held-out residual removed", _png(fig)))
    # How far: before/after time series of the accepted effects' affected channels.
    if d.accepted and d.final_fit is not None:
        fp, hp = d.problems
        shown = []
        for c in d.accepted:
            name = c.evaluation.affected
            if name in shown:
                continue
            shown.append(name)
            i = next(k for k, ch in enumerate(hp.channels) if ch.name == name)
            ch = hp.channels[i]
            rows = hp.holdout_rows[i]
            fig, ax = plt.subplots(figsize=(9, 3))
            ax.plot(ch.time[rows], predicted_residual(hp, i, d.base_fit, rows), ".", ms=1,
                    label="before (model)")
            ax.plot(ch.time[rows], predicted_residual(hp, i, d.final_fit, rows), ".", ms=1,
                    label="after (model + effect)")
            ax.set_xlabel("time [s]")
            ax.set_ylabel(f"held-out residual [{ch.unit}]")
            ax.legend(markerscale=8)
            figs.append((f"How far: {name}, held-out rows", _png(fig)))
    return figs


def write_report(d: Diagnosis, out: str | Path) -> tuple[Path, Path]:
    """Write ``gap.json`` and ``report.html`` into ``out`` (created). Returns both paths."""
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
            (out / "metadata.json").write_text(d.data_metadata.read_text())
    rows = "".join(
        f"<tr><td>{e['rank']}</td><td>{html.escape(e['name'])}</td><td>{html.escape(e['variant'])}</td>"
        f"<td>{e['magnitude']:.4g} {html.escape(e['unit'])}</td>"
        f"<td>[{e['ci'][0]:.3g}, {e['ci'][1]:.3g}]</td><td>{e['p_value']:.2g}</td>"
        f"<td>{100 * e['holdout_shrink']:.1f} % ({html.escape(e['affected_channel'])})</td>"
        f"<td>{'yes' if e['significant'] else 'no'}</td>"
        f"<td>{'yes' if e['identifiability']['separable'] else 'no'}</td></tr>"
        for e in gap["effects"] if e["magnitude"] is not None)
    sim = "".join(
        f"<tr><td>{html.escape(n)}</td><td>{s['before']['rms']:.4g}</td><td>{s['after']['rms']:.4g}</td>"
        f"<td>{s['before']['unit']}</td><td>{100 * s['shrink']:.1f} %</td></tr>"
        for n, s in d.simulation.items() if s["before"]["rms"] == s["before"]["rms"])
    figs = "".join(f"<h3>{html.escape(t)}</h3><img src='data:image/png;base64,{p}'/>" for t, p in _figures(d))
    page = f"""<!DOCTYPE html><html><head><meta charset="utf-8"><title>Sim-to-real gap</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}td,th{{padding:2px 8px;text-align:right}}
td:nth-child(2),td:nth-child(3){{text-align:left}}</style></head><body>
<h1>Sim-to-real gap diagnosis</h1>
<p><b>Verdict: {html.escape(d.verdict)}</b></p>
<p>Model: {html.escape(d.model_source)} — data: {html.escape(d.data_source)} — held out: {html.escape(d.holdout)}</p>
<p>Structured residual (whiteness / input correlation): {html.escape(', '.join(d.structured) or 'none')}</p>
<h2>Which: hypotheses</h2><table><tr><th>#</th><th>effect</th><th>variant</th><th>magnitude</th>
<th>95 % CI</th><th>p</th><th>held-out shrink</th><th>significant</th><th>separable</th></tr>{rows}</table>
<h2>How far: forward simulation (1 s windows from the measured state)</h2>
<table><tr><th>channel</th><th>RMS before</th><th>RMS after</th><th>unit</th><th>shrink</th></tr>{sim}</table>
<h2>Figures</h2>{figs}
</body></html>"""
    html_path = out / REPORT_HTML
    html_path.write_text(page)
    return json_path, html_path
