"""The default full campaign's excitation designs compared on the emulator, one command:

    python benchmarks/excitation.py [--seeds 0 1 2 3 4] [--workers 2] [--work DIR]

For the prototype and the heavy platform (emulator/data/heavy_platform.toml) and each noise seed, the
full campaign (``qomni campaign``, single-axis B_w included) runs once with the ``richness`` design and
once with the ``min_cond`` design (docs/identification.md, "Optimised excitation"), then
``qomni compare`` checks the parameters against the emulator's truth. Printed per vehicle and design:
cond(Θ̂₁ᵀΘ̂₁) planned (:func:`qomni.ident.planned_regressor.planned_condition`) and measured (median
and largest), the straight's and the rotation's planned RMS acceleration, each
parameter's relative error (mean |e| over the seeds and the largest), the largest error of each run (mean
over the seeds), the occupied rectangle, the peak |motor torque| of each identification step and the
share of its cycles at the drives' torque limit; then min_cond / richness ratios. Every campaign takes
≈ 40 s of one core.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))                 # this checkout's qomni, not an installed one

from qomni.datasheet import DataSheet  # noqa: E402
from qomni.ident.campaign import IDENTIFICATION_STEPS, CampaignSettings, plan  # noqa: E402
from qomni.ident.planned_regressor import planned_condition  # noqa: E402
from qomni.ident.rundir import load_repaired_run, step_signals  # noqa: E402

VEHICLES = {"prototype": None, "heavy_platform": str(ROOT / "emulator" / "data" / "heavy_platform.toml")}
CRITERIA = ("richness", "min_cond")


def run_case(work: Path, vehicle: str, criterion: str, seed: int) -> dict:
    """One campaign and its comparison with the truth; the figures of :func:`figures`."""
    out = work / f"{vehicle}_{criterion}_{seed}"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    cli = [sys.executable, "-m", "qomni.cli"]
    where = ["--vehicle", VEHICLES[vehicle]] if VEHICLES[vehicle] else []
    for args in (["campaign", "--out", str(out), "--seed", str(seed), "--excitation", criterion, "--force"],
                 ["compare", str(out)]):
        done = subprocess.run(cli + args + where, env=env, capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"{' '.join(args)} failed:\n{done.stdout[-2000:]}{done.stderr[-2000:]}")
    return figures(out)


def figures(run: Path) -> dict:
    ident = json.loads((run / "identification.json").read_text())
    comparison = json.loads((run / "comparison.json").read_text())
    meta = json.loads((run / "metadata.json").read_text())
    signals, sheet, _, _ = load_repaired_run(run, repair=False)
    limit = sheet.drive.max_torque
    torque = {}
    for step in IDENTIFICATION_STEPS:
        u = np.abs(step_signals(signals, step).motor_torque)
        torque[step] = (float(u.max()), float(np.mean(u.max(axis=1) >= 0.999 * limit)))
    return {"cond": ident["condition_number"],
            "error": {k: 100 * v["relative_error"] for k, v in comparison["parameters"].items()},
            "rectangle": (meta["occupied_rectangle"]["length"], meta["occupied_rectangle"]["width"]),
            "torque": torque}


def summary(rows: list[dict]) -> dict:
    names = list(rows[0]["error"])
    errors = np.array([[r["error"][n] for n in names] for r in rows])
    return {"cond": float(np.median([r["cond"] for r in rows])),
            "cond_max": float(np.max([r["cond"] for r in rows])),
            "mean_abs": dict(zip(names, np.mean(np.abs(errors), axis=0))),
            "max_abs": dict(zip(names, np.max(np.abs(errors), axis=0))),
            "run_max": float(np.mean(np.max(np.abs(errors), axis=1))),
            "rectangle": rows[0]["rectangle"],
            "torque": {s: (max(r["torque"][s][0] for r in rows), max(r["torque"][s][1] for r in rows))
                       for s in IDENTIFICATION_STEPS}}


def planned_accel(sheet: DataSheet, criterion: str) -> dict[str, float]:
    """RMS planned acceleration (m/s², rad/s²) of the straight and the rotation with ``criterion``."""
    out = {}
    for step in plan(sheet, CampaignSettings(excitation=criterion)):
        if step.name in ("straight", "rotation"):
            ((_, trajectory),) = step.trajectories.items()
            _, _, qdd = trajectory.evaluate(np.arange(0.0, trajectory.duration, sheet.drive.cycle_time))
            out[step.name] = float(np.sqrt(np.mean(qdd ** 2)))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--work", type=Path, default=None,
                        help="keep the runs here (default: a temporary folder)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        cases = [(v, c, s) for v in VEHICLES for s in args.seeds for c in CRITERIA]
        with ThreadPoolExecutor(args.workers) as pool:
            results = list(pool.map(lambda case: run_case(work, *case), cases))
        by = {}
        for (v, c, _), r in zip(cases, results):
            by.setdefault((v, c), []).append(r)
        for v, path in VEHICLES.items():
            sheet = DataSheet.load(path)
            s = {c: summary(by[(v, c)]) for c in CRITERIA}
            planned = {c: planned_condition(sheet, CampaignSettings(excitation=c)) for c in CRITERIA}
            print(f"\n{v}, seeds {args.seeds}")
            print(f"{'':24s}" + "".join(f"{c:>22s}" for c in CRITERIA) + f"{'ratio':>10s}")
            line = lambda label, a, b, f="{:22.2f}": print(  # noqa: E731
                f"{label:24s}" + f.format(a) + f.format(b) + f"{b / a if a else float('nan'):10.2f}")
            line("cond planned", planned["richness"], planned["min_cond"])
            line("cond measured (median)", s["richness"]["cond"], s["min_cond"]["cond"])
            line("cond measured (max)", s["richness"]["cond_max"], s["min_cond"]["cond_max"])
            accel = {c: planned_accel(sheet, c) for c in CRITERIA}
            for step in ("straight", "rotation"):
                line(f"RMS accel planned {step}", accel["richness"][step], accel["min_cond"][step])
            for name in s["richness"]["mean_abs"]:
                cells = (f"{s[c]['mean_abs'][name]:15.2f} / {s[c]['max_abs'][name]:4.2f}" for c in CRITERIA)
                print(f"{'|e| % ' + name + ' mean/max':24s}" + "".join(cells))
            line("largest |e| % per run", s["richness"]["run_max"], s["min_cond"]["run_max"])
            line("rectangle length m", s["richness"]["rectangle"][0], s["min_cond"]["rectangle"][0])
            line("rectangle width m", s["richness"]["rectangle"][1], s["min_cond"]["rectangle"][1])
            for step in IDENTIFICATION_STEPS:
                line(f"peak |u| N m {step}", s["richness"]["torque"][step][0],
                     s["min_cond"]["torque"][step][0])
                print(f"{'  cycles at the limit':24s}" + "".join(
                    f"{100 * s[c]['torque'][step][1]:21.1f}%" for c in CRITERIA))
    return 0


if __name__ == "__main__":
    sys.exit(main())
