"""Forward selection names further effects until a round names none: no fixed limit on their number (a
vehicle may have more unmodelled effects than the suite's triples)."""
from __future__ import annotations

from types import SimpleNamespace

from qomni.diagnosis import diagnose


def test_selection_goes_on_past_three_effects_until_a_round_names_none(monkeypatch):
    further = ["wheel_radius", "actuator_delay", "stribeck (joints=wheels)", "payload"]
    seen = []

    def accept_more(fp, hp, model, lag, sheet, accepted_fits, accepted, cache, levels, hypotheses,
                    floor=None, rows=None, log=None):
        seen.append([c.hypothesis.label for c in accepted])
        log.append({"beside": seen[-1], "named": further[0] if further else None, "tested": []})
        if not further:
            return None
        label = further.pop(0)
        return SimpleNamespace(hypothesis=SimpleNamespace(label=label)), f"joint fit with {label}"

    monkeypatch.setattr(diagnose, "_accept_more", accept_more)
    monkeypatch.setattr(diagnose, "_tail_fit", lambda h, joint_fit: f"{h.label} fit")
    accepted = [SimpleNamespace(hypothesis=SimpleNamespace(label="rolling_resistance"))]
    fits, selection = ["rolling_resistance fit"], []
    diagnose._forward_selection(None, None, None, 0, None, fits, accepted, {}, {}, [], None, None, selection)

    labels = [c.hypothesis.label for c in accepted]
    assert labels == ["rolling_resistance", "wheel_radius", "actuator_delay", "stribeck (joints=wheels)", "payload"]
    assert fits == [f"{label} fit" for label in labels]
    # every round saw the effects accepted before it; the last one named none and ended selection
    assert seen == [labels[:k] for k in range(1, 6)]
    assert len(selection) == 5 and selection[-1]["named"] is None
