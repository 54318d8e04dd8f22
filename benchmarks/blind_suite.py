"""Blind check of the sim-to-real gap diagnosis, in one command:

    python benchmarks/blind_suite.py                   # full: 5 draws per effect, pairs, triples, other
                                                       # vehicles, clean cases; full campaigns; twin reference
    python benchmarks/blind_suite.py --reference ideal # the same cases against an ideal emulator's model
    python benchmarks/blind_suite.py --quick           # 1 draw per effect, quick campaigns
    python benchmarks/blind_suite.py --master-seed 7   # the suite of master seed 7 (default: a new one)
    python benchmarks/blind_suite.py --scheduler tcp://HOST:PORT   # the cases as tasks of a Dask cluster
    python benchmarks/blind_suite.py --probe --dask-vs-local 4     # a local Dask cluster on 127.0.0.1
                                                       # against local processes, same tasks, same run
    python benchmarks/blind_suite.py --range-ends      # a quick campaign at both ends of every effect's
                                                       # realistic range: completed, peak torque / limit
    python benchmarks/blind_suite.py --range-ends --campaigns full --effects E ...   # full ones
    python benchmarks/blind_suite.py --withhold --work W   # each recorded single-effect case of W diagnosed
                                                       # against its twin without its effect's hypothesis

The cases are drawn from a master seed (qomni.suite.cases), new for every new work directory and
recorded in ``<work>/blind_suite.json`` with each case's draw (``blind_suite_ideal.json`` with
``--reference ideal``: both reference modes can score the same recordings). Prints top-1 accuracy, false positives and
held-out shrinkage per effect and rewrites the results file after every finished case; started again on
the same work directory, the suite takes its master seed from the file and runs only the cases not in
it. A case's campaign already in ``--work`` is re-used (its run directory holds ``identification.json``).
``--probe`` runs a worker check instead of campaigns (each task builds its case's emulator and steps it).
Ray is not offered: its head binds every interface, loopback or not.
"""
from __future__ import annotations

import argparse
import inspect
import os
import secrets
import sys
import time
from pathlib import Path

# One case per worker process: BLAS threads on top of the workers oversubscribe the cores. Set before
# numpy loads, so that the forked local workers and a local Dask cluster's inherit it.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rich.console import Console  # noqa: E402
from rich.table import Table  # noqa: E402
from rich.text import Text  # noqa: E402

from qomni.blind_suite import draw_cases, probe_case, read_run, run_suite, write_results  # noqa: E402


#: The results file of each reference mode in the work directory.
RESULTS = {"twin": "blind_suite.json", "ideal": "blind_suite_ideal.json"}


def dask_vs_local(todo, work: Path, quick: bool, workers, runner, console) -> int:
    """The same tasks on local processes and on a local Dask cluster bound to 127.0.0.1; wall times."""
    from distributed import Client, LocalCluster

    n = workers or 2
    started = time.perf_counter()
    local = run_suite(todo, work / "local", quick=quick, workers=n, runner=runner)
    t_local = time.perf_counter() - started
    with LocalCluster(host="127.0.0.1", n_workers=n, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        started = time.perf_counter()
        remote = run_suite(todo, work / "dask", quick=quick, executor=client.get_executor(), runner=runner)
        t_dask = time.perf_counter() - started
    errors = [r.error for r in local + remote if r.error]
    console.print(f"{len(todo)} tasks, {n} workers: local processes {t_local:.1f} s, Dask on 127.0.0.1 "
                  f"{t_dask:.1f} s (ratio {t_dask / t_local:.2f})" + (f"; errors: {errors}" if errors else ""))
    return 1 if errors else 0


def range_ends(work: Path, entries, console, quick: bool = True) -> int:
    """A campaign (quick, or full with ``quick`` false) at each end of every effect's realistic range
    (qomni.suite.range_ends), in turn; prints the table, writes ``work/range_ends.json`` after every row and
    returns 1 if any did not complete inside its limits."""
    from qomni.suite.range_ends import campaign_margins, range_end_cases

    kind = "quick" if quick else "full"
    table = Table(title=f"Campaign at the ends of each effect's realistic range ({kind} campaigns)")
    for col in ("Effect", "Table", "Completed", "Peak torque / limit", "At clip", "Straight |x| / x_max",
                "Probe dead time", "Steering bw"):
        table.add_column(col, justify="left" if col in ("Effect", "Table") else "right")
    from dataclasses import asdict

    from qomni.ident.rundir import write_json

    failed, started, rows = 0, time.perf_counter(), []
    for i, (entry, effects) in enumerate(range_end_cases(entries)):
        out = work / f"{i:02d}_{entry}"
        if out.exists():
            import shutil

            shutil.rmtree(out)
        row = campaign_margins(effects, out, seed=1 + i, quick=quick)
        failed += not row.completed
        rows.append(dict(asdict(row), entry=entry, completed=row.completed))
        write_json(work / "range_ends.json", {"rows": rows})
        params = ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                           for t in effects.values() for k, v in t.items())
        dead = row.probe.get("dead_time")
        table.add_row(entry, params, "yes" if row.completed else f"NO ({row.status})",
                      f"{row.peak_torque_ratio:.2f}", f"{100 * row.clipped:.1f} %",
                      f"{row.excursion / row.room:.2f}", "–" if dead is None else f"{1000 * dead:.0f} ms",
                      f"{row.probe.get('steering_bandwidth', float('nan')):.1f}")
        console.print(f"{entry} {params}: {'completed' if row.completed else 'NOT completed'}, peak "
                      f"{row.peak_torque_ratio:.2f} of the limit ({time.perf_counter() - started:.0f} s)",
                      markup=False)
    console.print(table)
    return 1 if failed else 0


def _diagnose_withheld(run_dir: str, name: str) -> str:
    """Verdict on one case against its twin with hypothesis ``name`` left out (a worker process)."""
    from qomni.diagnosis.diagnose import diagnose_paths
    from qomni.twin import TWIN_REFERENCE

    d = Path(run_dir)
    try:
        return diagnose_paths(d / "identification.json", d, reference_dir=d / TWIN_REFERENCE, simulate=False,
                              withhold=(name,)).verdict
    except Exception as exc:  # a failed case is reported, not fatal to the check
        return f"error: {type(exc).__name__}: {exc}"


def withheld(work: Path, workers, console) -> int:
    """Every single-effect case of the twin-reference results in ``work`` diagnosed against its recorded twin
    with its own effect's hypothesis left out of the library: flagged as unexplained structure, named as
    another effect (a false explanation), or not seen."""
    from concurrent.futures import ProcessPoolExecutor

    from qomni.blind_suite import read_results
    from qomni.diagnosis.diagnose import VERDICT_NONE, VERDICT_UNEXPLAINED
    from qomni.twin import TWIN_REFERENCE

    cases = [r.case for r in read_results(work / RESULTS["twin"])
             if len(r.case.truth) == 1 and (work / r.case.name / TWIN_REFERENCE / "signals.csv").exists()]
    if not cases:
        console.print(f"{work} holds no single-effect case with its twin recorded", markup=False)
        return 2
    counts = {"unexplained": 0, "other effect": 0, "none": 0, "error": 0}
    with ProcessPoolExecutor(max_workers=workers) as pool:
        verdicts = pool.map(_diagnose_withheld, [str(work / c.name) for c in cases], [c.truth[0] for c in cases])
        for case, verdict in zip(cases, verdicts):
            kind = ("unexplained" if VERDICT_UNEXPLAINED in verdict else "none" if verdict.endswith(VERDICT_NONE)
                    else "error" if verdict.startswith("error") else "other effect")
            counts[kind] += 1
            console.print(f"{case.name:45s} without {case.truth[0]:22s} → {verdict}", markup=False)
    console.print(f"{len(cases)} cases, own hypothesis withheld: "
                  + ", ".join(f"{k} {v}" for k, v in counts.items()), markup=False)
    return 1 if counts["error"] else 0


def _run(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="1 draw per effect, quick campaigns")
    ap.add_argument("--campaigns", choices=("quick", "full"), default=None,
                    help="campaign length (default: the results file's, else quick with --quick, else full)")
    ap.add_argument("--singles", type=int, default=None,
                    help="draws per effect (default: the results file's, else 5, 1 with --quick)")
    ap.add_argument("--pairs", type=int, default=None,
                    help="two-effect cases (default: the results file's, else 10)")
    ap.add_argument("--triples", type=int, default=None,
                    help="three-effect cases (default: the results file's, else 3)")
    ap.add_argument("--master-seed", type=int, default=None,
                    help="the suite's master seed (default: the results file's, else a new random one)")
    ap.add_argument("--reference", choices=("twin", "ideal"), default="twin",
                    help="diagnose against each case's own twin (default) or an ideal emulator's model; each "
                    "has its own results file in --work, so both can score the same recordings")
    ap.add_argument("--range-ends", action="store_true",
                    help="only the campaign at both ends of every effect's realistic range (quick campaigns, "
                    "or full ones with --campaigns full)")
    ap.add_argument("--work", type=Path, default=Path("runs/blind_suite"), help="work directory")
    ap.add_argument("--workers", type=int, default=None, help="local worker processes (default: cores)")
    ap.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                    help="run the cases on this Dask distributed scheduler's workers")
    ap.add_argument("--probe", action="store_true", help="worker check: no campaigns, each task steps its "
                    "case's emulator")
    ap.add_argument("--dask-vs-local", type=int, default=None, metavar="N",
                    help="time N tasks on a local Dask cluster bound to 127.0.0.1 against local processes")
    ap.add_argument("--effects", nargs="*", default=None, help="only these suite entries")
    ap.add_argument("--withhold", action="store_true",
                    help="diagnose each recorded single-effect case against its twin without its own effect's "
                    "hypothesis (unexplained structure, another effect, or nothing)")
    ap.add_argument("--recorded-only", action="store_true",
                    help="diagnose only the cases already recorded in --work (no new campaigns)")
    ap.add_argument("--twin-runs", type=int, default=None, metavar="K",
                    help="runs of each case's twin campaign on independent noise draws, the data diagnosed "
                         "beyond their mean residual (default: the results file's, else 1)")
    args = ap.parse_args(argv)
    console = Console() if sys.stdout.isatty() else Console(width=200)
    if args.range_ends:
        return range_ends(args.work / ("range_ends" if args.campaigns != "full" else "range_ends_full"),
                          args.effects, console, quick=args.campaigns != "full")
    if args.withhold:
        return withheld(args.work, args.workers, console)
    results_path = args.work / RESULTS[args.reference]
    runs = {mode: read_run(args.work / f) for mode, f in RESULTS.items() if (args.work / f).exists()}
    recorded = runs.get(args.reference, {})
    # The recordings in a work directory are one master seed's, whichever reference scores them.
    seeds = {r["master_seed"] for r in runs.values() if "master_seed" in r}
    master = args.master_seed if args.master_seed is not None else \
        (min(seeds) if seeds else secrets.randbits(31))
    if seeds - {master}:
        console.print(f"{args.work} holds the suite of master seed {min(seeds - {master})}; "
                      f"use another --work for master seed {master}", markup=False)
        return 2
    # A work directory holds one suite: what its results file records is the default, and a different
    # campaign length, draw count or entry list would score other cases than those recorded there.
    singles = args.singles or recorded.get("singles") or (1 if args.quick else 5)
    campaigns = args.campaigns or ("quick" if args.quick else recorded.get("campaigns", "full"))
    # a results file from before --pairs/--triples holds a suite drawn with draw_cases' defaults
    counts = {**{k: inspect.signature(draw_cases).parameters[k].default for k in ("pairs", "triples")},
              **recorded}
    pairs = args.pairs if args.pairs is not None else counts["pairs"]
    triples = args.triples if args.triples is not None else counts["triples"]
    effects = args.effects if args.effects is not None else recorded.get("effects")
    # a results file from before --twin-runs diagnosed against one twin run
    twin_runs = args.twin_runs or recorded.get("twin_runs", 1)
    if twin_runs < 1 or (twin_runs > 1 and args.reference != "twin"):
        console.print("--twin-runs needs a positive count, and more than 1 only with the twin reference",
                      markup=False)
        return 2
    held = {"twin_runs": 1, **counts} if recorded and args.reference == "twin" else counts if recorded else {}
    for key, value in (("campaigns", campaigns), ("singles", singles), ("pairs", pairs), ("triples", triples),
                       ("effects", effects),
                       ("reference", args.reference), ("twin_runs", twin_runs)):
        if key in held and held[key] != value:
            console.print(f"{results_path} holds a suite with {key} = {held[key]!r}, not {value!r}; "
                          f"use another --work", markup=False)
            return 2
    todo = draw_cases(master, singles=singles, pairs=pairs, triples=triples, entries=effects)
    run = {"master_seed": master, "reference": args.reference, "campaigns": campaigns, "singles": singles,
           "pairs": pairs, "triples": triples, "effects": effects,
           **({"twin_runs": twin_runs} if twin_runs > 1 else {})}
    if args.recorded_only:
        todo = [c for c in todo if (args.work / c.name / "identification.json").exists()]
    console.print(f"{len(todo)} cases of master seed {master} in {args.work} ({campaigns} campaigns, "
                  f"{args.reference} reference" + (f", {twin_runs} twin runs" if twin_runs > 1 else "") + ")",
                  markup=False)
    started = time.perf_counter()

    def show(r):
        mark = Text("✓", "green") if r.top1 and not r.false_positives else Text("✗", "red")
        console.print(mark, Text(f"{r.case.name:40s} → {r.verdict or r.error}  ({r.wall_time:.0f} s)"))

    runner = probe_case if args.probe else None
    if args.dask_vs_local:
        return dask_vs_local(todo[:args.dask_vs_local], args.work, campaigns == "quick", args.workers, runner,
                             console)
    executor, client = None, None
    if args.scheduler:
        from distributed import Client

        client = Client(args.scheduler)
        executor = client.get_executor()
    try:
        results = run_suite(todo, args.work, quick=campaigns == "quick", workers=args.workers, executor=executor,
                            results_path=None if args.probe else results_path, on_result=show,
                            runner=runner, reference=args.reference, run=run, twin_runs=twin_runs)
    finally:
        if client is not None:
            client.close()
    if args.probe:
        return 0 if not any(r.error for r in results) else 1
    summary = write_results(results, results_path, run)
    table = Table(title="Blind check per effect")
    for col in ("Effect", "Cases", "Top-1", "False positives", "Median held-out shrink", "Min shrink",
                "Median shrink beyond floor", "Min beyond floor", "Median gap shrink", "Min gap shrink",
                "Median from base fit", "Min from base fit",
                "Missed at range position"):
        table.add_column(col, justify="left" if col == "Effect" else "right")
    for name, e in sorted(summary["per_effect"].items()):
        fmt = (lambda v: "–" if v is None else f"{100 * v:.0f} %")
        table.add_row(name, str(e["cases"]), f"{e['top1']}/{e['cases']}", str(e["false_positives"]),
                      fmt(e["median_holdout_shrink"]), fmt(e["min_holdout_shrink"]),
                      fmt(e["median_excess_shrink"]), fmt(e["min_excess_shrink"]),
                      fmt(e.get("median_gap_shrink")), fmt(e.get("min_gap_shrink")),
                      fmt(e["median_beyond_base_fit_shrink"]), fmt(e["min_beyond_base_fit_shrink"]),
                      " ".join(f"{x:.2f}" for x in e.get("missed_range_positions", [])) or "–")
    console.print(table)
    acc = summary["top1_accuracy"]
    combos = summary["combinations_all_named"]
    console.print(f"master seed {master}, {args.reference} reference: top-1 accuracy "
                  f"{100 * (acc or 0):.1f} % over {summary['effect_cases']} single-effect cases; clean cases with "
                  f"a false positive {summary['clean_cases_with_false_positive']}/{summary['ideal_cases']}; all "
                  f"effects named in {combos['2'][0]}/{combos['2'][1]} pairs and {combos['3'][0]}/{combos['3'][1]} "
                  f"triples; cases with a false positive {summary['cases_with_false_positive']}; "
                  f"{time.perf_counter() - started:.0f} s wall")
    for err in summary["errors"]:
        console.print(Text("error", "red"), Text(str(err)))
    return 0 if not summary["errors"] else 1


def main(argv=None) -> int:
    """The suite (:func:`_run`); a results file gone bad, or one that holds another draw, is printed plainly
    and ends it with exit status 2 (no traceback, the file left as it is)."""
    from qomni.ident.rundir import RunDirectoryError

    try:
        return _run(argv)
    except RunDirectoryError as exc:
        Console(markup=False, highlight=False).print(f"error: {exc}")
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
