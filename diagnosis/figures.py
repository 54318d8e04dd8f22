"""The report's figures (matplotlib, Agg), each returned as a base64 PNG: where the residual is (over the
campaign, by regime and band), which hypotheses explain it (forest plot), how far it shrinks (held-out
RMS and forward simulation), the diagnosed data beside the reference run (the model's digital twin).

Every number plotted is one the diagnosis computed (:class:`diagnosis.diagnose.Diagnosis`, its ``where``
breakdown, evaluations and simulation); nothing here fits or simulates.
"""
from __future__ import annotations

import base64
import io

import numpy as np

from .diagnose import Diagnosis, _effect_term
from .where import BANDS


def unit_text(unit: str) -> str:
    """A unit as printed beside a number: nothing for a dimensionless quantity ("-", "1")."""
    return "" if unit in ("-", "1") else unit


DATA_COLOR = "tab:blue"
TWIN_COLOR = "tab:gray"
EFFECT_COLOR = "tab:red"
#: Regimes of :func:`diagnosis.where.regimes`, in the report's order ("sticking" = below the stiction
#: threshold, the others over the moving rows).
REGIMES = (("near_standstill", "sticking"), ("slow", "slow"), ("fast", "fast"),
           ("low_acceleration", "low |acc|"), ("high_acceleration", "high |acc|"),
           ("small_steering_angle", "|α| ≤ 0.2"), ("large_steering_angle", "|α| > 0.2"))


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def png(fig) -> str:
    """The figure as base64 PNG text (closed afterwards)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    _plt().close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def overlay_effects(d: Diagnosis) -> tuple[list, str]:
    """The effects whose predicted residual the time series overlay: the accepted ones, else the top
    ranked hypothesis (marked as not accepted). Returns (candidates, legend label)."""
    if d.accepted:
        return d.accepted, " + ".join(c.hypothesis.label for c in d.accepted) + " (predicted)"
    if d.candidates and d.candidates[0].fit is not None:
        top = d.candidates[0]
        return [top], f"{top.hypothesis.label} (top ranked, not accepted)"
    return [], ""


def _by_step(channels) -> dict:
    out: dict = {}
    for i, ch in enumerate(channels):
        out.setdefault(ch.step, []).append(i)
    return out


def _shade_unfitted(ax, ch, label=None) -> None:
    """Grey spans over the rows the fit leaves out (below the stiction threshold: sticking)."""
    free = ~np.asarray(ch.fitted, bool)
    if free.any() and not free.all():
        ax.fill_between(ch.time, 0, 1, where=free, transform=ax.get_xaxis_transform(), color="0.88",
                        step="mid", lw=0, label=label)


def residual_series(d: Diagnosis) -> list[tuple[str, str]]:
    """One figure per campaign step: each channel's residual (measured − model) over the step's time,
    the overlaid effect's predicted residual, and the reference run's residual in the same channel."""
    plt = _plt()
    effects, label = overlay_effects(d)
    fp = d.problems[0] if d.problems else None
    ref = {ch.name: ch for ch in d.reference_channels}
    figs = []
    for step, idx in _by_step(d.channels).items():
        cols = 2 if ref else 1
        fig, axes = plt.subplots(len(idx), cols, figsize=(11 if ref else 8, 1.7 * len(idx) + 0.6),
                                 squeeze=False, sharex="col")
        for row, i in enumerate(idx):
            ch = d.channels[i]
            ax = axes[row, 0]
            ax.plot(ch.time, ch.residual, color=DATA_COLOR, lw=0.6, label="residual (data)")
            _shade_unfitted(ax, ch, label="not fitted (sticking)" if row == 0 else None)
            term = _effect_term(fp, i, effects) if fp is not None and effects else None
            if term is not None and np.any(term):
                ax.plot(ch.time, term, color=EFFECT_COLOR, lw=1.2, label=label)
            ax.set_ylabel(f"{ch.name.split('/', 1)[-1]}\n[{ch.unit}]", fontsize=8)
            if row == 0:
                ax.set_title(f"{step}: data", fontsize=9)
                ax.legend(fontsize=7, loc="upper right")
            if ref:
                rax = axes[row, 1]
                r = ref.get(ch.name)
                if r is not None:
                    rax.plot(r.time, r.residual, color=TWIN_COLOR, lw=0.6)
                    _shade_unfitted(rax, r)
                    lim = max(np.max(np.abs(ch.residual), initial=0), np.max(np.abs(r.residual), initial=0))
                    if lim > 0:
                        ax.set_ylim(-1.05 * lim, 1.05 * lim)
                        rax.set_ylim(-1.05 * lim, 1.05 * lim)
                if row == 0:
                    rax.set_title(f"{step}: reference (twin), same scale", fontsize=9)
        for ax in axes[-1]:
            ax.set_xlabel("time [s]")
        fig.tight_layout()
        figs.append((f"{step}: residual over the step", png(fig)))
    return figs


def _regime_grid(where: dict, names: list[str]) -> np.ndarray:
    return np.array([[where.get(n, {}).get("regimes", {}).get(k, {}).get("rms", np.nan)
                      / max(where.get(n, {}).get("rms_residual", np.nan) or np.nan, 1e-300)
                      for k, _ in REGIMES] for n in names], dtype=float)


def regimes_and_bands(d: Diagnosis) -> tuple[str, str] | None:
    """Torque channels: RMS residual per regime relative to the channel's RMS (data | reference, one
    colour scale), and the residual's power per frequency band (data bar above the reference's)."""
    names = [n for n, w in d.where.items() if w["kind"] == "torque"]
    if not names:
        return None
    plt = _plt()
    panels = [("data", d.where)] + ([("reference (twin)", d.reference_where)] if d.reference_where else [])
    fig, axes = plt.subplots(1, len(panels) + 1, figsize=(5 * (len(panels) + 1), 0.38 * len(names) + 2),
                             gridspec_kw={"width_ratios": [1.2] * len(panels) + [1]})
    grids = [_regime_grid(w, names) for _, w in panels]
    vmax = max(1.5, float(np.nanmax([np.nanmax(g) if np.isfinite(g).any() else 0 for g in grids])))
    for k, ((title, _), g) in enumerate(zip(panels, grids)):
        ax = axes[k]
        im = ax.imshow(g, aspect="auto", cmap="magma", vmin=0, vmax=vmax)
        ax.set_xticks(range(len(REGIMES)), [lab for _, lab in REGIMES], rotation=35, ha="right", fontsize=8)
        ax.set_yticks(range(len(names)), names if k == 0 else [""] * len(names), fontsize=8)
        ax.set_title(f"{title}: RMS per regime / channel RMS", fontsize=9)
    fig.colorbar(im, ax=axes[len(panels) - 1], fraction=0.05)
    ax = axes[-1]
    band_names = [f"{lo:g}-{hi:g} Hz" for lo, hi in BANDS]
    colors = _plt().get_cmap("viridis")(np.linspace(0, 0.9, len(band_names)))
    h = 0.8 / len(panels)
    for k, (title, w) in enumerate(panels):
        y = np.arange(len(names)) + (k - (len(panels) - 1) / 2) * h
        left = np.zeros(len(names))
        for b, c in zip(band_names, colors):
            v = np.array([w.get(n, {}).get("bands", {}).get(b, 0.0) for n in names])
            ax.barh(y, 100 * v, height=h * 0.9, left=100 * left, color=c,
                    alpha=1.0 if k == 0 else 0.45, label=b if k == 0 else None)
            left += v
    ax.set_yticks(range(len(names)), [""] * len(names))
    ax.set_ylim(len(names) - 0.5, -0.5)
    ax.set_xlabel("residual power per band [%]")
    ax.set_title("bands (solid: data, pale: reference)" if len(panels) > 1 else "bands", fontsize=9)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    return "Where: operating regimes and frequency bands (torque channels)", png(fig)


def forest(d: Diagnosis, top: int = 15) -> tuple[str, str] | None:
    """Forest plot of the ranked hypotheses: held-out residual removed in the affected channel with its
    window-bootstrap 95 % interval (accepted: green), and each one's magnitude, interval and p."""
    rows = [c for c in d.candidates if c.magnitude.value is not None][:top]
    if not rows:
        return None
    plt = _plt()
    accepted = {id(c) for c in d.accepted}
    fig, ax = plt.subplots(figsize=(11, 0.42 * len(rows) + 1.2))
    y = np.arange(len(rows))
    for k, c in enumerate(rows):
        ev = c.from_model
        color = "tab:green" if id(c) in accepted else ("tab:olive" if c.significant else "tab:gray")
        lo, hi = ev.shrink_affected_ci
        ax.plot([100 * lo, 100 * hi], [k, k], color=color, lw=2)
        ax.plot(100 * ev.shrink_affected, k, "o", color=color, ms=6)
        m = c.magnitude
        unit = f" {unit_text(m.unit)}" if unit_text(m.unit) else ""
        ax.annotate(f"{m.value:.4g}{unit} [{m.ci[0]:.4g}, {m.ci[1]:.4g}]  p = {c.p_value:.2g}",
                    (1.01, k), xycoords=("axes fraction", "data"), va="center", fontsize=8)
    ax.axvline(0, color="k", lw=0.8)
    ax.set_yticks(y, [c.hypothesis.label for c in rows], fontsize=8)
    ax.set_ylim(len(rows) - 0.5, -0.5)
    ax.set_xlabel("held-out residual removed in the affected channel [%] (95 % bootstrap interval)")
    ax.set_title("green: accepted; olive: significant, not accepted; grey: not significant; "
                 "right: magnitude [95 % CI], p", fontsize=8)
    fig.tight_layout()
    return "Which: hypotheses ranked (forest plot)", png(fig)


#: Held-out RMS beyond this share of the data's (model) RMS is drawn clipped, its value written.
HOLDOUT_CLIP = 300.0


def holdout_bars(d: Diagnosis) -> tuple[str, str] | None:
    """Held-out RMS per channel relative to the model's on the data: the data under the model with the
    accepted effects (its bootstrap 95 % interval in the affected channel), and the reference run under
    the model without and with them."""
    before = d.model_holdout_rms
    if not before:
        return None
    after = ({s.name: s.rms_after for s in d.accepted[-1].from_model.channels} if d.accepted else {})
    ref = d.reference_holdout_rms
    names = [n for n in before if before[n] > 0]
    bars = [("data: model", DATA_COLOR, {n: before[n] for n in names})]
    if after:
        bars.append(("data: model + accepted effects", EFFECT_COLOR, after))
    if ref.get("model"):
        bars.append(("reference (twin): model", TWIN_COLOR, ref["model"]))
    if ref.get("with_effects"):
        bars.append(("reference (twin): + accepted effects", "tab:pink", ref["with_effects"]))
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 0.17 * len(names) * len(bars) + 1.4))
    y = np.arange(len(names))
    h = 0.85 / len(bars)
    for k, (label, color, vals) in enumerate(bars):
        rel = np.array([100 * vals.get(n, np.nan) / before[n] for n in names])
        pos = y + (k - (len(bars) - 1) / 2) * h
        ax.barh(pos, np.minimum(rel, HOLDOUT_CLIP), height=h * 0.9, color=color, label=label)
        for p_, v in zip(pos, rel):
            if v > HOLDOUT_CLIP:
                ax.annotate(f"{v:.0f} %", (HOLDOUT_CLIP, p_), va="center", fontsize=7, xytext=(2, 0),
                            textcoords="offset points")
    if after:
        off = (1 - (len(bars) - 1) / 2) * h
        for c in d.accepted:
            ev = c.from_model
            if ev.affected in names:
                k = names.index(ev.affected)
                lo, hi = ev.shrink_affected_ci
                ax.plot([100 * (1 - hi), 100 * (1 - lo)], [k + off, k + off], color="k", lw=2)
    ax.axvline(100, color="k", lw=0.6, ls=":")
    ax.set_xlim(0, HOLDOUT_CLIP * 1.12)
    ax.set_yticks(y, names, fontsize=8)
    ax.set_ylim(len(names) - 0.5, -0.5)
    ax.set_xlabel("held-out RMS residual, % of the model's on the data "
                  "(black: 95 % bootstrap interval in the affected channel)")
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    return "How far: held-out residual per channel", png(fig)


def simulation_bars(d: Diagnosis) -> tuple[str, str] | None:
    """Forward-simulation RMS error per torque channel before/after, data and reference."""
    sims = [("data", d.simulation)] + ([("reference (twin)", d.reference_simulation)]
                                       if d.reference_simulation else [])
    names = [n for n, s in d.simulation.items() if s["before"]["rms"] == s["before"]["rms"]]
    if not names:
        return None
    plt = _plt()
    fig, axes = plt.subplots(1, len(sims), figsize=(5.5 * len(sims), 0.4 * len(names) + 1.4),
                             squeeze=False)
    for ax, (title, sim) in zip(axes[0], sims):
        y = np.arange(len(names))
        for off, key, color in ((-0.2, "before", DATA_COLOR), (0.2, "after", EFFECT_COLOR)):
            ax.barh(y + off, [sim.get(n, {}).get(key, {}).get("rms", np.nan) for n in names], height=0.38,
                    color=color, label=f"{key}")
        ax.set_yticks(y, names if ax is axes[0][0] else [""] * len(names), fontsize=8)
        ax.set_ylim(len(names) - 0.5, -0.5)
        unit = sim[names[0]]["before"]["unit"] if names[0] in sim else ""
        ax.set_xlabel(f"forward-simulation RMS error [{unit}]")
        ax.set_title(title, fontsize=9)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return "How far: forward simulation before/after the accepted effects", png(fig)
