"""Shared by the diagnosis tests: a run diagnosed through the CLI against the digital twin of the model
identified on it."""
import json
import subprocess
import sys


def diagnose_against_own_twin(run, out) -> dict:
    """``qomni diagnose`` of a run against the twin of the model identified on it (the CLI runs the twin's
    campaign into ``out``); its gap.json."""
    result = subprocess.run([sys.executable, "-m", "qomni.cli", "diagnose", "--model",
                             str(run / "identification.json"), "--data", str(run), "--out", str(out),
                             "--no-simulate"], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
    return json.loads((out / "gap.json").read_text())
