"""The FMUs as an importer meets them: an FMU state restores the instance's mode (a state set into a
freshly instantiated instance steps at once, FMI 2.0 §2.1.8 / FMI 3.0 §2.2.6.4), inputs are checked when
set (non-finite values, plant torques beyond the data sheet's max_torque, feed-forward steering angles
beyond the stops are refused; min/max declared), and the plant's mode transitions happen where the
trajectory reaches them, not where the communication grid samples it."""
import shutil

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
from fmpy import read_model_description  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402

from qomni.datasheet import DataSheet  # noqa: E402
from qomni.fmu.cosim import MOTOR_TORQUE, FmuSlave  # noqa: E402
from qomni.fmu.export import export_feedforward_fmu, export_plant_fmu  # noqa: E402
from qomni.ident import kinematics  # noqa: E402
from doubles import identification  # noqa: E402

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")

SHEET = DataSheet.load()
OBSERVED = ["x_w", "x_ch_dot", "motor_position.rr", "alpha_l"]


@pytest.fixture(scope="session")
def plant_fmus(tmp_path_factory):
    d = tmp_path_factory.mktemp("plant_state")
    return {v: export_plant_fmu(identification(), SHEET, d / f"plant{v}.fmu", v) for v in (2, 3)}


def _state_api(fmu, version):
    if version == 2:
        return fmu.getFMUstate, fmu.setFMUstate, fmu.serializeFMUstate, fmu.deSerializeFMUstate
    return fmu.getFMUState, fmu.setFMUState, fmu.serializeFMUState, fmu.deserializeFMUState


@pytest.mark.parametrize("version", [2, 3])
def test_a_serialized_state_restores_into_a_freshly_instantiated_instance(plant_fmus, version):
    """fmusim's --initial-fmu-state-file: instantiate, deserialize, set the state, DoStep (no
    initialization calls). The restored instance continues exactly as the one that saved the state."""
    with FmuSlave(plant_fmus[version]) as saver:
        get, _, serialize, _ = _state_api(saver.fmu, version)
        saver.set_real(saver.refs(MOTOR_TORQUE), [2.0] * 4)
        saver.step(0.1)
        blob = serialize(get())
        saver.step(0.05)
        expected = saver.get_real(saver.refs(OBSERVED))
    from fmpy.fmi2 import FMU2Slave
    from fmpy.fmi3 import FMU3Slave

    with FmuSlave(plant_fmus[version]) as template:  # only for the unzipped directory and the references
        md, refs = template.model_description, template.refs(OBSERVED)
        cls = FMU2Slave if version == 2 else FMU3Slave
        fresh = cls(guid=md.guid, unzipDirectory=template._tmp, modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName="restored")
        fresh.instantiate()
        _, set_state, _, deserialize = _state_api(fresh, version)
        set_state(deserialize(blob))
        fresh.doStep(currentCommunicationPoint=0.1, communicationStepSize=0.05)
        got = np.array(fresh.getReal(refs) if version == 2 else fresh.getFloat64(refs))
        fresh.terminate()
        fresh.freeInstance()
    np.testing.assert_array_equal(got, expected)
    assert expected[1] > 0.1  # the vehicle moves: the state carried a chassis mode, not rest


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_a_non_finite_torque_is_refused_when_set(plant_fmus, version, value, capsys):
    with FmuSlave(plant_fmus[version]) as s:
        refs = s.refs(MOTOR_TORQUE)
        s.set_real(refs, [1.0] * 4)
        with pytest.raises(FMICallException):
            s.set_real(refs[2:3], [value])
        assert "input motor_torque.fr is not finite" in capsys.readouterr().out
        np.testing.assert_array_equal(s.get_real(refs), [1.0] * 4)  # the input kept its value
        s.step(0.01)


@pytest.mark.parametrize("version", [2, 3])
def test_torque_inputs_declare_and_enforce_the_data_sheets_max_torque(plant_fmus, version, capsys):
    limit = SHEET.drive.max_torque
    md = read_model_description(str(plant_fmus[version]))
    torques = [v for v in md.modelVariables if v.name in MOTOR_TORQUE]
    assert len(torques) == 4 and all(float(v.min) == -limit and float(v.max) == limit for v in torques)
    with FmuSlave(plant_fmus[version]) as s:
        refs = s.refs(MOTOR_TORQUE)
        s.set_real(refs, [limit, -limit, limit, -limit])  # the bounds themselves are admissible
        with pytest.raises(FMICallException):
            s.set_real(refs[:1], [limit * (1 + 1e-12)])
        assert "outside its declared range" in capsys.readouterr().out


def _trajectory(path, h, duration=0.6):
    """Drive 0.2 s, brake 0.1 s, then hold a torque below break-away: the chassis starts at t = 0 and comes
    to rest within a communication step. Returns the observed outputs at the end and the mode history."""
    with FmuSlave(path) as s:
        refs, ks = s.refs(MOTOR_TORQUE), []
        for j in range(round(duration / h)):
            t = j * h
            s.set_real(refs, [2.0 if t < 0.2 - 1e-12 else (-3.0 if t < 0.3 - 1e-12 else -0.04)] * 4)
            s.step(h)
            ks.append(s.get_int(s.refs(["k"]))[0])
        return s.get_real(s.refs(OBSERVED)), ks


def test_start_and_stop_of_motion_do_not_depend_on_the_communication_step(plant_fmus):
    """Leaving rest at t = 0 and coming to rest inside a step are located on the trajectory: h = 0.1 ms and
    h = 2 ms end at the same place up to RK4's truncation error (the sub-steps differ: 0.1 vs 0.25 ms;
    measured 2.5e-9 m), where taking the transitions at the end of a sub-step shifted the start and the stop
    by up to a sub-step of motion (1.3e-4 m here). Bound: 1e-8 m of travel (motor side: i_G / r times it)."""
    fine, ks_fine = _trajectory(plant_fmus[2], 1e-4)
    coarse, ks_coarse = _trajectory(plant_fmus[2], 2e-3)
    assert ks_fine[0] == ks_coarse[0] == 2 and ks_fine[-1] == ks_coarse[-1] == 1
    assert fine[0] > 0.05 and fine[1] == coarse[1] == 0.0  # moved, then at rest in both
    travel = 1e-8
    bound = np.array([travel, 0.0, travel * SHEET.drive.i_G / SHEET.geometry.r, 1e-12])
    assert np.all(np.abs(coarse - fine) <= bound), (coarse - fine, bound)


def test_feedforward_steering_inputs_declare_and_enforce_the_stops(tmp_path, capsys):
    ff = export_feedforward_fmu(identification(), SHEET, tmp_path / "ff3.fmu", 3)
    limit, av_max = SHEET.geometry.steering_limit, kinematics.alpha_v_max(SHEET.geometry)
    ranges = {v.name: (float(v.min), float(v.max)) for v in read_model_description(str(ff)).modelVariables
              if v.name in ("q.alpha_l", "q.alpha_r", "alpha_v")}
    assert ranges["q.alpha_l"] == ranges["q.alpha_r"] == (-limit, limit)
    assert ranges["alpha_v"] == pytest.approx((-av_max, av_max), rel=1e-15)
    with FmuSlave(ff) as s:
        s.set({"k": 3, "q.alpha_l": -limit, "q.alpha_r": limit})  # mode 3 sits on the stops
        with pytest.raises(FMICallException):
            s.set({"q.alpha_r": limit + 1e-9})
    assert "outside its declared range" in capsys.readouterr().out
