"""Running the blind suite: each case's campaign and diagnosis as a task of a ``concurrent.futures``
executor, the results back on the driver.

Two reference modes:

* ``twin`` (default, a real user's mode): the case's own campaign is identified, its digital twin
  (:mod:`qomni.twin`: the emulator with the identified parameters) runs the same campaign, and the case is
  diagnosed against that twin run (or the mean of ``twin_runs`` runs of it on independent noise draws).
  Nothing but the case's own data and its data sheet goes in.
* ``ideal``: every case is diagnosed against a model identified on an ideal emulator of its vehicle
  (one reference campaign per vehicle, run on the driver first).

Cases run on local processes by default, or on Dask distributed workers
(``distributed.Client(address).get_executor()``); each task runs its campaign in a process of its own (its
own PyBullet DIRECT client) with the case's seed and returns its result to the driver, which rewrites the
results file after every finished case and, started again, runs only the cases not in it. Ray is not
offered: on these machines a Ray head binds every interface whatever address it is given.
"""
from __future__ import annotations

import functools
import os
import socket
import subprocess
import sys
import time
from concurrent.futures import Executor, ProcessPoolExecutor, as_completed
from pathlib import Path

from .cases import VEHICLES, Case, effects_toml
from .scoring import CaseResult, read_results, write_results

REFERENCES = ("twin", "ideal")


def _description(case: Case):
    from qomni.emulator.description import VehicleDescription

    return VehicleDescription.load(VEHICLES[case.vehicle] if case.vehicle else None)


def run_campaign(out: Path, effects: dict | None, seed: int, quick: bool, vehicle: str = "") -> None:
    """One campaign, as ``qomni campaign`` runs it, on ``vehicle`` ("" the built-in one; a ``VEHICLES``
    key) with ``effects`` on its ideal bodies (None: the vehicle as built, the prototype's own units).
    What ``out`` holds is replaced (``--force``): the suite runs a case's campaign only where its run
    directory has no identification, i.e. an attempt of the same case cut short or failed.

    Raises:
        RuntimeError: the campaign command failed (its log's tail).
    """
    out.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "qomni.cli", "campaign", "--out", str(out), "--seed", str(seed), "--force"]
    if effects is not None:
        fx = out.parent / f"{out.name}.effects.toml"
        fx.write_text(effects_toml(effects))
        cmd += ["--effects", str(fx)]
    if vehicle:
        cmd += ["--vehicle", VEHICLES[vehicle]]
    cmd += ["--quick"] if quick else []
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    log = proc.stdout + proc.stderr
    (out.parent / f"{out.name}.log").write_text(log)
    if proc.returncode != 0:
        raise RuntimeError(f"campaign {out} failed ({proc.returncode}): {log.strip()[-800:]}")


def ideal_reference(work: Path, vehicle: str = "") -> Path:
    """Where the ideal-reference mode keeps ``vehicle``'s ideal campaign."""
    return Path(work) / ("reference_ideal" + (f"_{vehicle}" if vehicle else ""))


def reference_run(work: Path, quick: bool, seed: int = 1, vehicle: str = "") -> Path:
    """The ideal emulator's campaign (of ``vehicle``) whose identification is the ideal mode's model."""
    ref = ideal_reference(work, vehicle)
    if not (ref / "identification.json").exists():
        run_campaign(ref, {}, seed, quick, vehicle)
    return ref / "identification.json"


def run_case(case: Case, work: str, reference: str, quick: bool, twin_runs: int = 1) -> CaseResult:
    """Campaign and blind diagnosis of one case (in a worker process) against ``reference``: "twin" (the
    case's own identified model and ``twin_runs`` runs of its twin's campaign, :func:`qomni.twin.twin_references`)
    or "ideal" (the vehicle's ideal reference run)."""
    from qomni.diagnosis.diagnose import diagnose_paths
    from qomni.diagnosis.report import write_report
    from qomni.twin import TWIN_REFERENCE, twin_references

    started = time.perf_counter()
    result = CaseResult(case)
    run_dir = Path(work) / case.name
    try:
        if not (run_dir / "identification.json").exists():
            run_campaign(run_dir, None if case.prototype else case.effects, case.seed, quick, case.vehicle)
        if reference == "twin":
            model = run_dir / "identification.json"
            ref_dir, *repeats = twin_references(model, run_dir, run_dir / TWIN_REFERENCE, twin_runs)
        else:
            model = ideal_reference(Path(work), case.vehicle) / "identification.json"
            ref_dir, repeats = None, []
        d = diagnose_paths(model, run_dir, reference_dir=ref_dir, reference_repeats=repeats, simulate=False)
        write_report(d, run_dir / ("gap" if reference == "ideal" else "gap_twin"))
        _fill(result, d)
    except Exception as exc:  # a failed case is reported, not fatal to the suite
        result.error = f"{type(exc).__name__}: {exc}"
    result.wall_time = time.perf_counter() - started
    return result


def _fill(result: CaseResult, d) -> None:
    """The diagnosis' verdict, ranking and the true effects' shrinkage into ``result``."""
    case = result.case
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
            twin = (d.reference_holdout_rms.get("model") or {}).get(ev.affected)
            # a paired channel's residual is already the data's beyond the twin's at the same instants
            paired = ev.affected in d.paired_channels
            result.true_shrink[name] = {"shrink": ev.shrink_affected,
                                        "beyond_base_fit": c.shrink.shrink_affected,
                                        "beyond_reference": c.evaluation.shrink_affected,
                                        "rms_before": ch.rms_before if ch else None,
                                        "rms_after": ch.rms_after if ch else None,
                                        "reference_rms": twin,
                                        "paired": paired,
                                        "ci": list(ev.shrink_affected_ci),
                                        "channel": ev.affected,
                                        "magnitude": c.magnitude.value, "unit": c.magnitude.unit}


def run_suite(all_cases: list[Case], work: str | Path, *, quick: bool = True, workers: int | None = None,
              executor: Executor | None = None, results_path: str | Path | None = None, on_result=None,
              runner=None, reference: str = "twin", run: dict | None = None,
              twin_runs: int = 1) -> list[CaseResult]:
    """Run every case as tasks of ``executor`` (in the ideal mode, each vehicle's reference campaign
    first, on the driver).

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
        reference: "twin" or "ideal" (module docstring). run: recorded in the results file (master seed…).
        twin_runs: the twin reference's runs per case (:func:`run_case`; :func:`run_case` only).
    Returns:
        the results of every case, the resumed ones included.
    Raises:
        ValueError: an unknown reference mode, or ``twin_runs`` < 1.
        RunDirectoryError: the results file is not valid, or holds a finished case that is not one of
            ``all_cases`` as drawn (:func:`_check_recorded`).
    """
    if reference not in REFERENCES:
        raise ValueError(f"reference must be one of {REFERENCES}, not {reference!r}")
    if twin_runs < 1:
        raise ValueError(f"the twin needs at least one reference run, not {twin_runs}")
    work = Path(work)
    work.mkdir(parents=True, exist_ok=True)
    runner = runner or run_case
    if runner is run_case and reference == "ideal":
        for vehicle in sorted({c.vehicle for c in all_cases}):
            reference_run(work, quick, vehicle=vehicle)
    recorded = read_results(results_path) if results_path and Path(results_path).exists() else []
    _check_recorded(recorded, all_cases, results_path)
    # every finished record is a drawn case (checked above); one that ended in an error (a campaign cut
    # short, a worker lost) is run again
    results = [r for r in recorded if not r.error]
    done = {r.case.name for r in results}
    own = executor is None
    executor = executor or ProcessPoolExecutor(max_workers=workers or os.cpu_count() or 1)
    try:
        task = functools.partial(run_case, twin_runs=twin_runs) if runner is run_case else runner
        futures = [executor.submit(task, c, str(work), reference, quick) for c in all_cases
                   if c.name not in done]
        for f in as_completed(futures):
            r = f.result()
            results.append(r)
            if results_path:
                write_results(results, results_path, run)
            if on_result:
                on_result(r)
    finally:
        if own:
            executor.shutdown()
    return results


def _comparable(case: Case) -> str:
    """A case as its results file holds it (JSON: tuples become lists), for comparing a recorded case
    with the one drawn."""
    import json
    from dataclasses import asdict

    return json.dumps(asdict(case), sort_keys=True)


def _check_recorded(recorded: list[CaseResult], all_cases: list[Case], results_path) -> None:
    """Every finished case of the results file is one of the suite's cases exactly as drawn (effects,
    truth, seed, vehicle): a resume never scores an edited record, and never rewrites the file without the
    cases of another draw (another master seed), which it would drop.

    Raises: RunDirectoryError: names the case."""
    from qomni.ident.rundir import RunDirectoryError

    drawn = {c.name: _comparable(c) for c in all_cases}
    for r in recorded:
        if r.error or drawn.get(r.case.name) == _comparable(r.case):
            continue
        why = "is not a case of this draw (another master seed or count)" if r.case.name not in drawn else \
            "differs from the case drawn under that name (an edited record)"
        raise RunDirectoryError(f"{results_path}: case {r.case.name!r} {why}; the suite would drop or rescore "
                                "it: use another work directory, or the draw that recorded it")


def probe_case(case: Case, work: str, reference: str, quick: bool) -> CaseResult:
    """A task that checks a worker without a campaign: it builds the case's emulator with its effects and
    seed (its own PyBullet DIRECT client), runs a tenth of a second and reports where and what it saw."""
    from qomni.emulator.effects import EffectSet
    from qomni.emulator.vehicle import Emulator

    started = time.perf_counter()
    result = CaseResult(case)
    try:
        with Emulator(_description(case), effects=None if case.prototype else EffectSet.from_dict(case.effects),
                      seed=case.seed) as emu:
            emu.step(0.1)
            position = emu.read_sensors().motor_position.tolist()
        result.verdict = f"probe seed {case.seed} on {socket.gethostname()} pid {os.getpid()}: {position}"
    except Exception as exc:  # a failed task is reported, not fatal to the suite
        result.error = f"{type(exc).__name__}: {exc}"
    result.wall_time = time.perf_counter() - started
    return result
