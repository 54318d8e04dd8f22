"""Blind check of the gap diagnosis: campaigns on emulators with one known effect (or none, or two), the
diagnosis told nothing but the reference model and the data, scored against what was switched on.

Protocol
--------
* A reference campaign on the **ideal** emulator (no effect) gives the model: identified parameters
  that hold where the paper's assumptions hold.
* Every case runs a campaign on the ideal emulator plus its effects (effects file written per case,
  seed per case) and ``qomni diagnose --model REFERENCE --data CASE``.
* Scores: top-1 (the first accepted effect is the one switched on), false positives (accepted effects
  that were not switched on; any accepted effect on an ideal case), the held-out shrinkage of the true
  effect's hypothesis in its affected channel, and for two-effect cases whether both are named.

Cases are tasks on a ``concurrent.futures`` executor: local processes by default, or Dask distributed
workers (``distributed.Client(address).get_executor()``). Each task runs its campaign in a process of its
own (its own PyBullet DIRECT client) with the case's seed, and returns its result to the driver, which
writes the results file after every finished case and, started again, runs only the cases not in it.
Ray is not offered: on these machines a Ray head binds every interface whatever address it is given.
This module is part of the composition root: it writes effects files and knows the truth to score
against; the diagnosis itself never sees either.
"""
from __future__ import annotations

import json
import math
import os
import socket
import statistics
import subprocess
import sys
import time
from concurrent.futures import Executor, ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from qomni.conventions import WHEELS
from qomni.emulator.effects.effect_set import REGISTRY
from qomni.ident.rundir import write_json

#: Realistic magnitudes per effect: (low, high). Each entry is one effects-file table.
#: Realistic magnitudes per suite entry: (low, high) effects-file tables, as each effect declares them
#: (``Effect.suite`` in its module).
MAGNITUDES: dict[str, tuple[dict, dict]] = {entry: tables for cls in REGISTRY.values()
                                            for entry, tables in cls.suite.items()}
#: Effects-file table name of each suite entry (two Stribeck variants share one effect).
TABLE = {entry: cls.name for cls in REGISTRY.values() for entry in cls.suite if entry != cls.name}
DRIVES = WHEELS
#: Names of the magnitude indices 0 and 1 of MAGNITUDES.
LEVELS = ("low", "high")
#: Pairs run in the two-effect cases: (entry, magnitude index) each. A 10 ms delay together with a
#: 10 mrad backlash drives the campaign's steering loop into a limit cycle at the torque limit in every
#: step (the wheels spin; no model of rolling holds), so that pair runs the low delay.
PAIRS = ((("incline", 1), ("wheel_radius", 1)), (("actuator_delay", 0), ("backlash", 1)))


def effect_name(entry: str) -> str:
    """The effect name the diagnosis should report for a suite entry."""
    return TABLE.get(entry, entry)


def seeded_table(entry: str, magnitude: int, seed: int) -> dict:
    """The effects-file table for an entry at magnitude index 0/1; per-seed choices (an incline's
    direction, the faulty drive) vary with the seed."""
    table = dict(MAGNITUDES[entry][magnitude])
    if entry == "incline":
        # Any direction except within 25° of purely lateral to the campaign's driving direction: a
        # slope perpendicular to every motion of the campaign does no work on it and is invisible.
        heading = (0.9 * ((seed * 0.618034) % 1.0) - 0.45) * math.pi + (math.pi if seed % 2 else 0.0)
        table["uphill_heading"] = heading
    if entry == "torque_constant_error":
        table["drive"] = DRIVES[seed % 4]
    return table


def variant(entry: str, table: dict) -> str | None:
    """The hypothesis variant the diagnosis should name for an entry's table (None: any)."""
    if TABLE.get(entry) == "stribeck":
        return f"joints={table['joints']}"
    if entry == "torque_constant_error":
        return f"drive {table['drive']}"
    return None


def effects_toml(tables: dict[str, dict]) -> str:
    lines = []
    for name, table in tables.items():
        lines.append(f"[{name}]")
        for k, v in table.items():
            lines.append(f"{k} = {json.dumps(v)}")
        lines.append("")
    return "\n".join(lines)


@dataclass
class Case:
    """One campaign of the suite."""

    name: str
    effects: dict[str, dict]          # effects-file tables
    truth: list[str]                  # effect names the diagnosis should report
    seed: int
    magnitude: str = ""
    entry: str = ""                   # suite entry (MAGNITUDES key) of a one-effect case
    variants: dict[str, str] = field(default_factory=dict)  # effect name → the instance to name


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
            return not self.accepted
        return bool(self.accepted) and self._named(0)

    @property
    def all_named(self) -> bool:
        named = {self.accepted[k] for k in range(len(self.accepted)) if self._named(k)}
        return set(self.case.truth) <= named

    @property
    def false_positives(self) -> list[str]:
        return [a for k, a in enumerate(self.accepted) if not self._named(k)]


def cases(seeds: int = 5, magnitudes: tuple[int, ...] = (0, 1), entries=None, ideal: int | None = None,
          pairs: bool = True, first_seed: int = 100) -> list[Case]:
    """The suite: every entry × magnitudes × seeds, ``ideal`` ideal cases (default: ``seeds``) and the
    two-effect pairs (magnitudes as in PAIRS, one seed each)."""
    out = []
    for entry in entries or MAGNITUDES:
        for m in magnitudes:
            for s in range(seeds):
                seed = first_seed + 17 * s + m
                effects, truth, variants = _effects({entry: seeded_table(entry, m, seed)})
                out.append(Case(f"{entry}_{LEVELS[m]}_s{seed}", effects, truth, seed, LEVELS[m], entry,
                                variants))
    for s in range(seeds if ideal is None else ideal):
        out.append(Case(f"ideal_s{first_seed + s}", {}, [], first_seed + s))
    if pairs:
        for i, ((a, ma), (b, mb)) in enumerate(PAIRS):
            seed = first_seed + 500 + i
            tables = {a: seeded_table(a, ma, seed), b: seeded_table(b, mb, seed)}
            effects, truth, variants = _effects(tables)
            out.append(Case(f"{a}_{LEVELS[ma]}+{b}_{LEVELS[mb]}_s{seed}", effects, truth, seed,
                            f"{LEVELS[ma]}+{LEVELS[mb]}", variants=variants))
    return out


def _effects(tables: dict[str, dict]) -> tuple[dict, list[str], dict]:
    """Suite entries' tables → (effects-file tables, effect names to report, variants to name)."""
    variants = {effect_name(e): v for e, t in tables.items() if (v := variant(e, t)) is not None}
    return {effect_name(e): t for e, t in tables.items()}, [effect_name(e) for e in tables], variants


def run_campaign(out: Path, effects: dict, seed: int, quick: bool) -> None:
    """One campaign on the ideal emulator plus ``effects``, as ``qomni campaign`` runs it."""
    out.mkdir(parents=True, exist_ok=True)
    fx = out.parent / f"{out.name}.effects.toml"
    fx.write_text(effects_toml(effects))
    cmd = [sys.executable, "-m", "qomni.cli", "campaign", "--out", str(out), "--effects", str(fx),
           "--seed", str(seed)] + (["--quick"] if quick else [])
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    (out.parent / f"{out.name}.log").write_text(proc.stdout + proc.stderr)
    if proc.returncode != 0:
        raise RuntimeError(f"campaign {out} failed ({proc.returncode}): {proc.stderr[-800:]}")


def run_case(case: Case, work: str, reference: str, quick: bool) -> CaseResult:
    """Campaign + blind diagnosis of one case (runs in a worker process or a Ray task)."""
    from qomni.diagnosis.diagnose import diagnose_paths
    from qomni.diagnosis.report import write_report

    started = time.perf_counter()
    result = CaseResult(case)
    run_dir = Path(work) / case.name
    try:
        if not (run_dir / "identification.json").exists():
            run_campaign(run_dir, case.effects, case.seed, quick)
        d = diagnose_paths(Path(reference), run_dir, simulate=False)
        write_report(d, run_dir / "gap")
        result.verdict = d.verdict
        result.accepted = [c.hypothesis.name for c in d.accepted]
        result.accepted_variants = [c.hypothesis.variant for c in d.accepted]
        result.ranking = [c.hypothesis.name for c in d.candidates]
        result.holdout_rms = dict(d.holdout_rms)
        result.model_holdout_rms = dict(d.model_holdout_rms)
        for name in case.truth:
            want = case.variants.get(name)
            c = next((c for c in d.candidates if c.hypothesis.name == name
                      and (want is None or c.hypothesis.variant == want)), None)
            if c is not None:
                ev = c.from_model
                ch = next((s for s in ev.channels if s.name == ev.affected), None)
                result.true_shrink[name] = {"shrink": ev.shrink_affected,
                                            "beyond_base_fit": c.shrink.shrink_affected,
                                            "beyond_reference": c.evaluation.shrink_affected,
                                            "rms_before": ch.rms_before if ch else None,
                                            "rms_after": ch.rms_after if ch else None,
                                            "ci": list(ev.shrink_affected_ci),
                                            "channel": ev.affected,
                                            "magnitude": c.magnitude.value, "unit": c.magnitude.unit}
    except Exception as exc:  # a failed case is reported, not fatal to the suite
        result.error = f"{type(exc).__name__}: {exc}"
    result.wall_time = time.perf_counter() - started
    return result


def reference_run(work: Path, quick: bool, seed: int = 1) -> Path:
    """The ideal emulator's campaign whose identification is the diagnosed model."""
    ref = work / "reference_ideal"
    if not (ref / "identification.json").exists():
        run_campaign(ref, {}, seed, quick)
    return ref / "identification.json"


def run_suite(all_cases: list[Case], work: str | Path, *, quick: bool = True, workers: int | None = None,
              executor: Executor | None = None, results_path: str | Path | None = None, on_result=None,
              runner=None) -> list[CaseResult]:
    """Run every case (the reference campaign first, on the driver) as tasks of ``executor``.

    Args:
        all_cases: the cases; work: the directory their runs go to (shared by the workers).
        quick: quick campaigns. workers: local processes when no executor is given (default: cores).
        executor: any ``concurrent.futures.Executor`` (a Dask cluster's ``Client.get_executor()``);
            default a local process pool.
        results_path: the suite's results file (:func:`write_results`): the cases it already holds are
            not run again, and it is rewritten atomically after every finished case, so a suite that
            stops resumes where it stopped.
        on_result: called with each finished :class:`CaseResult`.
        runner: ``(case, work, reference, quick) -> CaseResult``, default :func:`run_case`.
    Returns:
        the results of every case, the resumed ones included.
    """
    work = Path(work)
    work.mkdir(parents=True, exist_ok=True)
    runner = runner or run_case
    reference = str(reference_run(work, quick)) if runner is run_case else ""
    wanted = {c.name for c in all_cases}
    results = [r for r in (read_results(results_path) if results_path and Path(results_path).exists() else [])
               if r.case.name in wanted]
    done = {r.case.name for r in results}
    own = executor is None
    executor = executor or ProcessPoolExecutor(max_workers=workers or os.cpu_count() or 1)
    try:
        futures = [executor.submit(runner, c, str(work), reference, quick) for c in all_cases
                   if c.name not in done]
        for f in as_completed(futures):
            r = f.result()
            results.append(r)
            if results_path:
                write_results(results, results_path)
            if on_result:
                on_result(r)
    finally:
        if own:
            executor.shutdown()
    return results


def probe_case(case: Case, work: str, reference: str, quick: bool) -> CaseResult:
    """A task that checks a worker without a campaign: it builds the case's emulator with its effects and
    seed (its own PyBullet DIRECT client), runs a tenth of a second and reports where and what it saw."""
    from qomni.emulator.effects import EffectSet
    from qomni.emulator.vehicle import Emulator

    started = time.perf_counter()
    result = CaseResult(case)
    try:
        with Emulator(effects=EffectSet.from_dict(case.effects), seed=case.seed) as emu:
            emu.step(0.1)
            position = emu.read_sensors().motor_position.tolist()
        result.verdict = f"probe seed {case.seed} on {socket.gethostname()} pid {os.getpid()}: {position}"
    except Exception as exc:  # a failed task is reported, not fatal to the suite
        result.error = f"{type(exc).__name__}: {exc}"
    result.wall_time = time.perf_counter() - started
    return result


def noise_floor(ideal: list[CaseResult]) -> dict[str, float]:
    """Per channel, the held-out RMS the reference model, as identified, leaves on the ideal cases (their
    quadratic mean): what no effect can remove, since the ideal emulator has none. Results written before
    that RMS was recorded give the base fit's instead."""
    sums: dict[str, list[float]] = {}
    for r in ideal:
        for name, rms in (r.model_holdout_rms or r.holdout_rms).items():
            sums.setdefault(name, []).append(rms**2)
    return {name: math.sqrt(sum(v) / len(v)) for name, v in sums.items()}


def excess_shrink(rms_before: float, rms_after: float, floor: float) -> float | None:
    """1 − RMS(after)/RMS(before) of the residual beyond the noise floor (the ideal cases' RMS in the same
    channel, taken as independent of the effect's residual): the share of the effect's own held-out
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
    fit (``*_beyond_base_fit_shrink``: base parameters moved within their prior first) and from the
    reference run's level of the hypothesis (``median_beyond_reference_shrink``, the significance
    gate's)."""
    single = [r for r in results if len(r.case.truth) == 1 and not r.error]
    ideal = [r for r in results if not r.case.truth and not r.error]
    pairs = [r for r in results if len(r.case.truth) > 1 and not r.error]
    floor = noise_floor(ideal)
    per_effect: dict[str, dict] = {}
    for r in single:
        e = per_effect.setdefault(r.case.entry or r.case.truth[0], {"cases": 0, "top1": 0, "false_positives": 0,
                                                                    "shrink": [], "excess": [], "base": [],
                                                                    "beyond": []})
        e["cases"] += 1
        e["top1"] += int(r.top1)
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
    for e in per_effect.values():
        s, x, bf, b = e.pop("shrink"), e.pop("excess"), e.pop("base"), e.pop("beyond")
        e["median_holdout_shrink"] = float(statistics.median_high(s)) if s else None
        e["min_holdout_shrink"] = float(min(s)) if s else None
        e["median_excess_shrink"] = float(statistics.median_high(x)) if x else None
        e["min_excess_shrink"] = float(min(x)) if x else None
        e["median_beyond_base_fit_shrink"] = float(statistics.median_high(bf)) if bf else None
        e["min_beyond_base_fit_shrink"] = float(min(bf)) if bf else None
        e["median_beyond_reference_shrink"] = float(statistics.median_high(b)) if b else None
    return {
        "top1_accuracy": sum(r.top1 for r in single) / len(single) if single else None,
        "effect_cases": len(single),
        "ideal_cases": len(ideal),
        "ideal_false_positives": sum(len(r.accepted) for r in ideal),
        "pairs_both_named": sum(r.all_named for r in pairs),
        "pair_cases": len(pairs),
        "errors": [f"{r.case.name}: {r.error}" for r in results if r.error],
        "per_effect": per_effect,
        "noise_floor": floor,
    }


def write_results(results: list[CaseResult], path: str | Path) -> dict:
    """Write the scored results (atomically) and return the summary."""
    summary = score(results)
    data = {"summary": summary,
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
