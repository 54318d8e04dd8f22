"""Accuracy of the plant FMU against the emulator (fmu.accuracy): from the measured state at the start of
each 1 s window, the FMU fed with the recorded torques predicts the chassis pose after 1 s within 2 cm and
1 degree on the straight and rotation steps. Data: tests/data/fmu_accuracy_run, the first 2 s of both steps
of a quick campaign against the emulator (seed 0) with its identification.json."""
import gzip
import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("fmpy")

from qomni.fmu.accuracy import OUTPUTS, format_table, predict_windows  # noqa: E402

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")

DATA = Path(__file__).parent / "data" / "fmu_accuracy_run"


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("accuracy_run")
    for name in ("metadata.json", "identification.json"):
        shutil.copy(DATA / name, d / name)
    with gzip.open(DATA / "signals.csv.gz", "rb") as src, open(d / "signals.csv", "wb") as dst:
        shutil.copyfileobj(src, dst)
    return d


def test_pose_after_one_second_within_2_cm_and_1_degree(run_dir):
    results = predict_windows(run_dir, window=1.0, steps=("straight", "rotation"))
    table = format_table(results)
    print(table)
    assert [r.step for r in results] == ["straight", "rotation"] and all(r.windows == 2 for r in results)
    for r in results:
        assert r.end_position_max <= 0.02, table
        assert r.end_heading_max <= np.radians(1.0), table
        assert all(np.isfinite(r.rms[o]) for o in OUTPUTS)
        assert r.rms["alpha"] < 0.01 and r.rms["motor_velocity"] < 1.0, table  # rad, rad/s motor side
    with pytest.raises(ValueError):
        predict_windows(run_dir, window=0.001)
