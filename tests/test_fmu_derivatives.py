"""Exact directional derivatives (FMI 2 providesDirectionalDerivative, FMI 3 providesDirectionalDerivatives
and providesAdjointDerivatives): the feed-forward FMU's Jacobian of the motor torques by its inputs, from
the sympy-generated partial derivatives of (21), equals central finite differences of the FMU itself to
1e-6 relative over random states in every mode (mode 2 with alpha_v from alpha and from its input); the
adjoint is its transpose; the plant's outputs do not depend on its inputs directly (Jacobian 0)."""
import shutil
import zipfile
from xml.etree import ElementTree as ET

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
from fmpy import read_model_description  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402

from qomni.datasheet import DataSheet  # noqa: E402
from qomni.fmu.cosim import FmuSlave  # noqa: E402
from qomni.fmu.export import export_feedforward_fmu, export_plant_fmu  # noqa: E402
from qomni.ident import kinematics  # noqa: E402
from doubles import identification  # noqa: E402

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")

SHEET = DataSheet.load()
G = SHEET.geometry
KNOWNS = ["q.alpha_l", "q.alpha_r", "alpha_v", "s_dot[1]", "s_dot[2]", "s_ddot[1]", "s_ddot[2]"]
UNKNOWNS = [f"motor_torque.{w}" for w in ("fl", "rl", "fr", "rr")]
RELATIVE = 1e-6


@pytest.fixture(scope="session")
def feedforward_fmus(tmp_path_factory):
    d = tmp_path_factory.mktemp("ff_derivatives")
    return {v: export_feedforward_fmu(identification(), SHEET, d / f"ff{v}.fmu", v) for v in (2, 3)}


def _random_inputs(rng, k, from_alpha_v):
    """Inputs of mode k: mode 2 on the ICR manifold (alpha = f_ICR(alpha_v)), others anywhere within the
    stops; generalized velocities and accelerations of the vehicle's range."""
    av_max = kinematics.alpha_v_max(G)
    alpha_v = rng.uniform(-0.8, 0.8) * av_max
    alpha = kinematics.f_icr(alpha_v, G)[0] if k == 2 else rng.uniform(-1.3, 1.3, 2)
    values = {"q.alpha_l": alpha[0], "q.alpha_r": alpha[1], "alpha_v": alpha_v if from_alpha_v else 0.0}
    values.update({f"s_dot[{j}]": rng.normal(0, 0.5) for j in (1, 2)})
    values.update({f"s_ddot[{j}]": rng.normal(0, 2.0) for j in (1, 2)})
    return values


def _jacobian(s, version):
    unknowns, knowns = s.refs(UNKNOWNS), s.refs(KNOWNS)
    columns = []
    for j in range(len(knowns)):
        seed = np.zeros(len(knowns))
        seed[j] = 1.0
        columns.append(s.fmu.getDirectionalDerivative(unknowns, knowns, list(seed)))
    return np.array(columns).T


def _finite_differences(s, values):
    """Central differences, step 1e-7 of the input's scale: truncation ~ h^2 |u'''| and rounding
    ~ 1e-16 |u| / h. Near the tanh friction's knee (|v| ~ eps = 0.01 rad/s) u''' is large: over 100
    random mode-2 states the worst difference to the exact Jacobian scaled as h^2 (1e-2, 1e-4, 1e-6 at
    h = 1e-4, 1e-5, 1e-6; benchmarks/fmu_derivatives.py) and is 1.4e-8 at 1e-7."""
    out = s.refs(UNKNOWNS)
    J = np.zeros((4, len(KNOWNS)))
    for j, name in enumerate(KNOWNS):
        h = 1e-7 * max(1.0, abs(values[name]))
        s.set({name: values[name] + h})
        up = s.get_real(out)
        s.set({name: values[name] - h})
        down = s.get_real(out)
        s.set({name: values[name]})
        J[:, j] = (up - down) / (2 * h)
    return J


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("k, from_alpha_v", [(1, False), (2, False), (2, True), (3, False), (4, False)])
def test_directional_derivatives_equal_finite_differences(feedforward_fmus, version, k, from_alpha_v):
    rng = np.random.default_rng(100 * k + 10 * version + from_alpha_v)
    with FmuSlave(feedforward_fmus[version], {"use_alpha_v_input": from_alpha_v}) as s:
        for _ in range(6):
            values = _random_inputs(rng, k, from_alpha_v)
            s.set({"k": k, **values})
            exact, numeric = _jacobian(s, version), _finite_differences(s, values)
            scale = np.max(np.abs(exact), axis=1, keepdims=True)
            assert np.all(scale > 0)
            assert np.all(np.abs(exact - numeric) <= RELATIVE * scale), (k, values, exact - numeric)
            if version == 3:  # the adjoint is the transpose: seed^T J
                seed = rng.normal(size=4)
                adjoint = s.fmu.getAdjointDerivative(s.refs(UNKNOWNS), s.refs(KNOWNS), list(seed), len(KNOWNS))
                np.testing.assert_allclose(adjoint, seed @ exact, rtol=1e-12, atol=1e-12 * np.max(scale))


def test_model_descriptions_declare_the_derivatives(feedforward_fmus):
    assert read_model_description(str(feedforward_fmus[2])).coSimulation.providesDirectionalDerivative
    with zipfile.ZipFile(feedforward_fmus[3]) as zf:  # fmpy 0.3 reads the FMI 2 spelling for FMI 3
        cs = ET.fromstring(zf.read("modelDescription.xml")).find("CoSimulation")
    assert cs.get("providesDirectionalDerivatives") == cs.get("providesAdjointDerivatives") == "true"


def test_a_known_that_is_no_input_is_an_error(feedforward_fmus, capsys):
    with FmuSlave(feedforward_fmus[2]) as s:
        with pytest.raises(FMICallException):
            s.fmu.getDirectionalDerivative(s.refs(UNKNOWNS), s.refs(["C_l"]), [1.0])
    assert "known 'C_l'" in capsys.readouterr().out


def test_the_plant_outputs_have_no_direct_dependency_on_the_torques(tmp_path):
    path = export_plant_fmu(identification(), SHEET, tmp_path / "plant.fmu", 3)
    with FmuSlave(path) as s:
        s.set({f"motor_torque.{w}": 2.0 for w in ("fl", "rl", "fr", "rr")})
        s.step(0.05)
        outputs = [v.name for v in s.model_description.modelVariables
                   if v.causality == "output" and v.type == "Float64"]
        sensitivity = s.fmu.getDirectionalDerivative(s.refs(outputs), s.refs(["motor_torque.fl"]), [1.0])
        assert np.all(np.array(sensitivity) == 0.0)

