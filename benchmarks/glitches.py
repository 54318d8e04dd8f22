"""Parameter errors under glitches in the recording, per estimator, repaired and kept (docs/identification.md,
"Glitches in the recording").

    python benchmarks/glitches.py RUN_DIR [--vehicle VEHICLE.toml] [--fraction 0.01] [--seed 1]
        [--work DIR]

RUN_DIR is a campaign of the embedded emulator (``qomni campaign --quick --out DIR``). For each kind of
glitch a copy of the run gets it in ``--fraction`` of its rows (drawn at random; a stuck reading in bursts
of 25 rows), is identified with
wls, irls and consistent, with the glitches repaired (the default) and kept (``--keep-spikes``), and the
largest error of m_ch, C_ch, d_vw, d_cw against the vehicle's truth is printed. The copies are written
under --work (default: a temporary directory), one per kind, replaced on every run.
"""
from __future__ import annotations

import argparse
import csv
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

from qomni.cli.loaders import load_description
from qomni.ident.identify import identify
from qomni.ident.recording import WHEELS

CHASSIS = ("m_ch", "C_ch", "d_vw", "d_cw")
ESTIMATORS = ("wls", "irls", "consistent")
TORQUE = [f"motor_torque_{w} [N m motor]" for w in WHEELS]
POSITION = [f"motor_position_{w} [rad motor]" for w in WHEELS]
VELOCITY = [f"motor_velocity_{w} [rad/s motor]" for w in WHEELS]
ALPHA = ["alpha_l [rad]", "alpha_r [rad]"]


def _one(cols):
    return lambda rng: [cols[rng.integers(len(cols))]]


#: kind → (description, columns hit per row, new value from (old value, rng))
KINDS = {
    "torque_sat_all": ("torque actual +6 N m (0x6072), all four drives", lambda rng: TORQUE, lambda v, rng: 6.0),
    "torque_sat_one": ("torque actual ±6 N m, one drive", _one(TORQUE), lambda v, rng: 6.0 * rng.choice([-1, 1])),
    "torque_x10": ("torque actual × 10, one drive", _one(TORQUE), lambda v, rng: 10 * v),
    "torque_noise": ("torque actual + N(0, 3 N m), one drive", _one(TORQUE), lambda v, rng: v + rng.normal(0, 3)),
    "torque_zero": ("torque actual 0, all drives", lambda rng: TORQUE, lambda v, rng: 0.0),
    "position": ("motor position ± 10 rad, one drive", _one(POSITION), lambda v, rng: v + 10 * rng.choice([-1, 1])),
    "velocity": ("velocity actual ± 50 rad/s, one drive", _one(VELOCITY), lambda v, rng: v + 50 * rng.choice([-1, 1])),
    "alpha": ("steering angle ± 0.3 rad, one side", _one(ALPHA), lambda v, rng: v + 0.3 * rng.choice([-1, 1])),
    "row_zero": ("the whole row 0 (a dropped sample)", lambda rng: TORQUE + POSITION + VELOCITY + ALPHA,
                 lambda v, rng: 0.0),
    "any_column": ("one random column × U(−5, 5) + N(0, 5)", _one(TORQUE + POSITION + VELOCITY + ALPHA),
                   lambda v, rng: v * rng.uniform(-5, 5) + rng.normal(0, 5)),
    "torque_stuck": ("torque actual of one drive stuck at +6 N m for 50 ms (25 rows)", _one(TORQUE),
                     lambda v, rng: 6.0),
}
#: kind → rows each glitch spans (1 where not listed); a burst hits the same columns in each of its rows
BURST = {"torque_stuck": 25}


def glitched_copy(run_dir: Path, dest: Path, kind: str, fraction: float, seed: int) -> None:
    """Copy ``run_dir`` to ``dest`` with glitches of ``kind`` in ``fraction`` of the rows of signals.csv."""
    shutil.rmtree(dest, ignore_errors=True)
    shutil.copytree(run_dir, dest)
    with open(dest / "signals.csv", newline="") as f:
        rows = list(csv.reader(f))
    head, body = rows[0], rows[1:]
    at = {name: i for i, name in enumerate(head)}
    rng = np.random.default_rng(seed)
    _, columns, value = KINDS[kind]
    span = BURST.get(kind, 1)
    starts = rng.choice(len(body) - span, size=max(int(fraction * len(body) / span), 1), replace=False)
    for start in starts:
        names = columns(rng)
        for r in range(start, start + span):
            for name in names:
                body[r][at[name]] = repr(float(value(float(body[r][at[name]]), rng)))
    with open(dest / "signals.csv", "w", newline="") as f:
        csv.writer(f, lineterminator="\n").writerows([head, *body])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--vehicle", type=Path, default=None, help="vehicle description of the run (truth)")
    parser.add_argument("--fraction", type=float, default=0.01)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--work", type=Path, default=None)
    parser.add_argument("--kinds", nargs="*", default=list(KINDS), choices=list(KINDS), help="kinds to run")
    args = parser.parse_args(argv)
    truth = load_description(args.vehicle).truth
    work = args.work or Path(tempfile.mkdtemp(prefix="qomni_glitches_"))

    def error(run, estimator, repair):
        result, _ = identify(run, torque_lag=0.0, estimator=estimator, repair_spikes=repair)
        return max(abs(result.values[n] / getattr(truth, n) - 1) for n in CHASSIS)

    header = [f"{e}{'' if repair else ', kept'}" for repair in (True, False) for e in ESTIMATORS]
    print(f"largest error of {', '.join(CHASSIS)} against the truth; clean run: "
          f"{100 * error(args.run_dir, 'wls', True):.1f} % (wls)")
    print("| glitch in {:.0%} of the rows | ".format(args.fraction) + " | ".join(header) + " |")
    print("|---" * (len(header) + 1) + "|")
    for kind in args.kinds:
        description = KINDS[kind][0]
        dest = work / kind
        glitched_copy(args.run_dir, dest, kind, args.fraction, args.seed)
        cells = [f"{100 * error(dest, e, repair):.1f} %" for repair in (True, False) for e in ESTIMATORS]
        print(f"| {description} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
