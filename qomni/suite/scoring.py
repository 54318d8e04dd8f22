"""Scoring of the blind suite: what each case's diagnosis named against what was switched on, the summary
over the suite, and the results file (written atomically after every case, read again to resume).
"""
from __future__ import annotations

import math
import statistics
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from qomni.ident.rundir import write_json

from .cases import Case, effect_name, range_position


@dataclass
class CaseResult:
    case: Case
    verdict: str = ""
    accepted: list[str] = field(default_factory=list)
    accepted_variants: list[str] = field(default_factory=list)
    ranking: list[str] = field(default_factory=list)
    true_shrink: dict = field(default_factory=dict)
    holdout_rms: dict = field(default_factory=dict)   # channel → the base fit's held-out RMS
    model_holdout_rms: dict = field(default_factory=dict)  # channel → the model as identified's
    wall_time: float = 0.0
    error: str = ""

    def _named(self, k: int) -> bool:
        """Whether accepted effect k is switched on, as the instance switched on (the Stribeck joints,
        the drive with the torque-constant error) where the case says which."""
        name = self.accepted[k]
        if name not in self.case.truth:
            return False
        want = self.case.variants.get(name)
        have = self.accepted_variants[k] if k < len(self.accepted_variants) else ""
        return want is None or have == want

    @property
    def top1(self) -> bool:
        if not self.case.truth:
            return not self.false_positives
        return bool(self.accepted) and self._named(0)

    @property
    def all_named(self) -> bool:
        named = {self.accepted[k] for k in range(len(self.accepted)) if self._named(k)}
        return set(self.case.truth) <= named

    @property
    def false_positives(self) -> list[str]:
        """Accepted effects not switched on (the case's tolerated ones, e.g. the prototype's own heavy
        steering units, excepted)."""
        return [a for k, a in enumerate(self.accepted) if not self._named(k) and a not in self.case.tolerated]


def noise_floor(ideal: list[CaseResult]) -> dict[str, float]:
    """Per channel, the held-out RMS the reference model, as identified, leaves on the ideal cases (their
    quadratic mean): what no effect can remove, since the ideal emulator has none. Results written before
    that RMS was recorded give the base fit's instead."""
    sums: dict[str, list[float]] = {}
    for r in ideal:
        for name, rms in (r.model_holdout_rms or r.holdout_rms).items():
            sums.setdefault(name, []).append(rms**2)
    return {name: math.sqrt(sum(v) / len(v)) for name, v in sums.items()}


def _range_position(r: CaseResult) -> float | None:
    """Where a single-effect case's table lies in its entry's realistic range (0 weak end, 1 strong end);
    None for a case without its suite entry (results written before it was recorded)."""
    entry = r.case.entry
    table = r.case.effects.get(effect_name(entry)) if entry else None
    position = None if table is None else range_position(entry, table)
    return None if position is None else round(position, 3)


def excess_shrink(rms_before: float, rms_after: float, floor: float) -> float | None:
    """1 − RMS(after)/RMS(before) of the residual beyond the noise floor (the ideal cases' RMS in the same
    channel, or what the model leaves there on the case's own reference run; taken as independent of the
    effect's residual): the share of the effect's own held-out
    residual that the fitted hypothesis removes. None when the channel is not above its floor."""
    excess_before = rms_before**2 - floor**2
    if excess_before <= 0:
        return None
    return 1.0 - math.sqrt(max(rms_after**2 - floor**2, 0.0) / excess_before)


def score(results: list[CaseResult]) -> dict:
    """Top-1 accuracy over effect cases, false positives (ideal and effect cases), two-effect naming and
    held-out shrinkage per effect once the named effect is added to the model as identified: of the whole
    residual in the affected channel (``*_holdout_shrink``) and of its part beyond the ideal cases' floor
    (``*_excess_shrink``, when the suite has ideal cases); and the same effect's shrinkage from the base
    fit (``*_beyond_base_fit_shrink``: base parameters moved within their prior first); of the gap, the
    residual beyond what the model leaves on the case's own reference run in the same channel (its twin's,
    or the ideal vehicle's: ``*_gap_shrink``, :func:`excess_shrink` with that run's held-out RMS as the
    floor, where the case records it and its residual is above it; in a channel paired with the twin
    sample by sample (``paired``, :mod:`qomni.diagnosis.paired`) the residual already is the data's beyond
    the twin's, so its gap shrink is the whole-residual shrink: subtracting the twin's RMS again would
    count the twin's floor twice); and from the
    reference run's level of the hypothesis (``median_beyond_reference_shrink``, the significance
    gate's); and where in the effect's realistic range its named and missed cases lie
    (``named_range_positions``, ``missed_range_positions``: 0 the weak end, 1 the strong end, sorted),
    which shows whether what is missed is the weak end or spread over the range."""
    single = [r for r in results if len(r.case.truth) == 1 and not r.error]
    ideal = [r for r in results if not r.case.truth and not r.error]
    clean = [r for r in ideal if not r.case.tolerated]      # the floor: vehicles with nothing unmodelled
    pairs = [r for r in results if len(r.case.truth) > 1 and not r.error]
    floor = noise_floor(clean)
    per_effect: dict[str, dict] = {}
    for r in single:
        e = per_effect.setdefault(r.case.entry or r.case.truth[0], {"cases": 0, "top1": 0, "false_positives": 0,
                                                                    "shrink": [], "excess": [], "gap": [], "base": [],
                                                                    "beyond": [], "named": [], "missed": []})
        e["cases"] += 1
        e["top1"] += int(r.top1)
        e["named" if r.top1 else "missed"].append(_range_position(r))
        e["false_positives"] += len(r.false_positives)
        t = r.true_shrink.get(r.case.truth[0])
        if t is not None:
            e["shrink"].append(t["shrink"])
            e["base"].append(t.get("beyond_base_fit", t["shrink"]))
            e["beyond"].append(t.get("beyond_reference", t["shrink"]))
            if t["channel"] in floor and t.get("rms_before") is not None:
                x = excess_shrink(t["rms_before"], t["rms_after"], floor[t["channel"]])
                if x is not None:
                    e["excess"].append(x)
            if t.get("paired"):
                e["gap"].append(t["shrink"])
            elif t.get("reference_rms") is not None and t.get("rms_before") is not None:
                x = excess_shrink(t["rms_before"], t["rms_after"], t["reference_rms"])
                if x is not None:
                    e["gap"].append(x)
    for e in per_effect.values():
        s, x, g, bf, b = e.pop("shrink"), e.pop("excess"), e.pop("gap"), e.pop("base"), e.pop("beyond")
        e["median_holdout_shrink"] = float(statistics.median_high(s)) if s else None
        e["min_holdout_shrink"] = float(min(s)) if s else None
        e["median_excess_shrink"] = float(statistics.median_high(x)) if x else None
        e["min_excess_shrink"] = float(min(x)) if x else None
        e["median_gap_shrink"] = float(statistics.median_high(g)) if g else None
        e["min_gap_shrink"] = float(min(g)) if g else None
        e["median_beyond_base_fit_shrink"] = float(statistics.median_high(bf)) if bf else None
        e["min_beyond_base_fit_shrink"] = float(min(bf)) if bf else None
        e["median_beyond_reference_shrink"] = float(statistics.median_high(b)) if b else None
        for kind in ("named", "missed"):
            e[f"{kind}_range_positions"] = sorted(x for x in e.pop(kind) if x is not None)
    return {
        "top1_accuracy": sum(r.top1 for r in single) / len(single) if single else None,
        "effect_cases": len(single),
        "ideal_cases": len(ideal),
        "ideal_false_positives": sum(len(r.false_positives) for r in ideal),
        "clean_cases_with_false_positive": sum(bool(r.false_positives) for r in ideal),
        "pairs_both_named": sum(r.all_named for r in pairs),
        "pair_cases": len(pairs),
        "combinations_all_named": {str(n): [sum(r.all_named for r in pairs if len(r.case.truth) == n),
                                            sum(len(r.case.truth) == n for r in pairs)] for n in (2, 3)},
        "cases_with_false_positive": sum(bool(r.false_positives) for r in results if not r.error),
        "errors": [f"{r.case.name}: {r.error}" for r in results if r.error],
        "per_effect": per_effect,
        "noise_floor": floor,
    }


def write_results(results: list[CaseResult], path: str | Path, run: dict | None = None) -> dict:
    """Write the scored results (atomically) and return the summary. ``run`` (the master seed, the
    reference mode, the campaign length) is recorded beside them; each case's draw is in its ``case``."""
    summary = score(results)
    data = {"run": run or {}, "summary": summary,
            "cases": [dict(asdict(r), top1=r.top1, false_positives=r.false_positives) for r in results]}
    write_json(Path(path), data)
    return summary


def read_results(path: str | Path) -> list[CaseResult]:
    """The case results of a results file written by :func:`write_results`.

    Raises:
        RunDirectoryError: the file is not valid JSON or a case is malformed (file and case named).
    """
    from qomni.ident.rundir import RunDirectoryError, read_json

    out = []
    names = {f.name for f in fields(CaseResult)}
    for i, item in enumerate(read_json(Path(path)).get("cases", [])):
        try:
            out.append(CaseResult(**{**{k: v for k, v in item.items() if k in names},
                                     "case": Case(**item["case"])}))
        except (KeyError, TypeError) as exc:
            raise RunDirectoryError(f"{path}: cases[{i}] is not a case result: {exc}") from None
    return out


def read_run(path: str | Path) -> dict:
    """The ``run`` record (master seed, reference mode, …) of a results file; {} when it has none."""
    from qomni.ident.rundir import read_json

    return dict(read_json(Path(path)).get("run", {}))
