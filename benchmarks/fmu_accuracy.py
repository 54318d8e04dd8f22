"""Prediction accuracy of the plant FMU on a recorded campaign: per campaign step the RMS error of every
output over 1 s windows started from the measured state, and the worst chassis pose error after 1 s
(acceptance: <= 2 cm and <= 1 degree on straight and rotation). See fmu.accuracy.

    python benchmarks/fmu_accuracy.py RUN_DIR [--window 1.0] [--fmu PLANT.fmu]

RUN_DIR is a campaign run directory with identification.json (``qomni campaign --quick --out DIR``).
"""
from __future__ import annotations

import argparse
import math
import sys

from qomni.fmu.accuracy import format_table, predict_windows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir")
    parser.add_argument("--window", type=float, default=1.0, help="window length, s")
    parser.add_argument("--fmu", default=None, help="plant FMU (default: exported from the run)")
    args = parser.parse_args(argv)
    results = predict_windows(args.run_dir, args.fmu, args.window)
    print(format_table(results))
    ok = all(r.end_position_max <= 0.02 and r.end_heading_max <= math.radians(1.0)
             for r in results if r.step in ("straight", "rotation"))
    print(f"acceptance (straight, rotation: end pose <= 2 cm, <= 1 deg): {'met' if ok else 'NOT met'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
