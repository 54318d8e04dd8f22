"""A second importer: the feed-forward and the plant FMU (FMI 2.0 and 3.0) simulated in ecospy (Vico /
libecos, C++ FMI host) give the same results as in fmpy, input sequence for input sequence."""
import ctypes
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

import fmpy  # noqa: F401  (the test extra installs it)

# ecospy's libecos needs libtbb.so.12: the Debian package libtbb12 where installed, else the one the test
# extra's ``tbb`` wheel puts into <prefix>/lib, loaded globally before ecospy so the linker finds it.
_TBB = Path(sys.prefix) / "lib" / "libtbb.so.12"
if _TBB.is_file():
    ctypes.CDLL(str(_TBB), mode=ctypes.RTLD_GLOBAL)
import ecospy  # noqa: E402

from qomni.fmu.cosim import MOTOR_TORQUE, REAL_OUTPUTS, FmuSlave  # noqa: E402
from qomni.fmu.export import export_feedforward_fmu, export_plant_fmu  # noqa: E402
from qomni.ident import kinematics  # noqa: E402
from qomni.datasheet import DataSheet  # noqa: E402
from doubles import identification  # noqa: E402

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")

SHEET = DataSheet.load()
G = SHEET.geometry
H = 0.002
N = 150
FF_INPUTS = ("q.alpha_l", "q.alpha_r", "s_dot[1]", "s_dot[2]", "s_ddot[1]", "s_ddot[2]")
FF_OUTPUTS = MOTOR_TORQUE


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    d = tmp_path_factory.mktemp("importers")
    out = {}
    for v in (2, 3):
        out["plant", v] = export_plant_fmu(identification(), SHEET, d / f"plant{v}.fmu", v)
        out["feedforward", v] = export_feedforward_fmu(identification(), SHEET, d / f"ff{v}.fmu", v)
    return out


def plant_inputs():
    """Motor torques (N, 4): steer at rest, align, drive with steering corrections, brake."""
    t = np.arange(N) * H
    u = np.zeros((N, 4))
    u[t < 0.06] = np.array([-1.2, 1.2, 1.4, -1.4])
    drive = t >= 0.1
    u[drive] = 2.0 + 0.4 * np.sin(20 * t[drive])[:, None] * np.array([-1, 1, 1, -1])
    u[t > 0.25] = -1.0
    return u


def ff_inputs():
    """(k (N,), real inputs (N, 6)): every mode in turn."""
    rng = np.random.default_rng(4)
    k = np.repeat([1, 2, 3, 4], -(-N // 4))[:N]
    x = rng.normal(0, 1, (N, 6))
    x[:, 0:2] = rng.uniform(-1.5, 1.5, (N, 2))  # within the stops (the FMU refuses angles beyond)
    for mode in (2, 3, 4):
        rows = k == mode
        x[rows, 0:2] = (kinematics.f_icr(rng.uniform(-0.5, 0.5, rows.sum()), G) if mode == 2
                        else kinematics.mode_alpha(mode, G))
    return k, x


def run_fmpy(path, kind):
    out = []
    with FmuSlave(path) as s:
        if kind == "plant":
            u_refs, y_refs = s.refs(MOTOR_TORQUE), s.refs(REAL_OUTPUTS)
            for u in plant_inputs():
                s.set_real(u_refs, u)
                s.step(H)
                out.append(s.get_real(y_refs))
        else:
            k, x = ff_inputs()
            x_refs, y_refs = s.refs(FF_INPUTS), s.refs(FF_OUTPUTS)
            for kk, xx in zip(k, x):
                s.set({"k": int(kk)})
                s.set_real(x_refs, xx)
                s.step(H)
                out.append(s.get_real(y_refs))
    return np.array(out)


def run_ecospy(path, kind):
    structure = ecospy.EcosSimulationStructure()
    structure.add_model("m", str(path))
    sim = ecospy.EcosSimulation(structure=structure, step_size=H)
    sim.init()
    out = []
    try:
        if kind == "plant":
            for u in plant_inputs():
                for name, value in zip(MOTOR_TORQUE, u):
                    sim.set_real(f"m::{name}", float(value))
                sim.step(1)
                out.append([sim.get_real(f"m::{n}") for n in REAL_OUTPUTS])
        else:
            k, x = ff_inputs()
            for kk, xx in zip(k, x):
                sim.set_integer("m::k", int(kk))
                for name, value in zip(FF_INPUTS, xx):
                    sim.set_real(f"m::{name}", float(value))
                sim.step(1)
                out.append([sim.get_real(f"m::{n}") for n in FF_OUTPUTS])
        assert sim.get_time() == pytest.approx(N * H)
    finally:
        sim.terminate()
        sim.free()
        structure.free()
    return np.array(out)


@pytest.mark.parametrize("kind", ["plant", "feedforward"])
@pytest.mark.parametrize("version", [2, 3])
def test_ecospy_and_fmpy_give_equal_results(fmus, kind, version):
    a = run_fmpy(fmus[kind, version], kind)
    b = run_ecospy(fmus[kind, version], kind)
    assert a.shape == b.shape == (N, len(REAL_OUTPUTS) if kind == "plant" else 4)
    assert np.all(np.isfinite(a)) and np.ptp(a, axis=0).max() > 0.1
    np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12)


@pytest.mark.skipif(shutil.which("fmutool") is None, reason="needs fmu-manipulation-toolbox (fmutool)")
@pytest.mark.parametrize("kind", ["plant", "feedforward"])
@pytest.mark.parametrize("version", [2, 3])
def test_the_model_descriptions_pass_the_fmi_schema_and_semantic_checks(fmus, kind, version):
    """The FMU Manipulation Toolbox's checker: the standard's XSD and its semantic rules."""
    import subprocess

    proc = subprocess.run(["fmutool", "-input", str(fmus[kind, version]), "-check"], capture_output=True,
                          text=True, timeout=300)
    text = proc.stdout + proc.stderr
    assert proc.returncode == 0 and "ERROR" not in text, text
    assert f"compliant with FMI-{version}.0" in text and f"No semantic error against the FMI-{version}" in text
