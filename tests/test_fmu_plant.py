"""The plant FMU (fmu.export.export_plant_fmu): generated C forward dynamics equal ident's numpy model,
fmpy validation, the hybrid behaviour in every mode equal to the numpy reference fmu.plant_reference,
variable communication step size, FMU state, errors."""
import ctypes
import shutil
import subprocess

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
from fmpy import read_model_description  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

from qomni.fmu import codegen  # noqa: E402
from qomni.fmu import plant_reference as R  # noqa: E402
from qomni.fmu.cosim import MOTOR_TORQUE, FmuSlave, PlantVehicle  # noqa: E402
from qomni.fmu.build import c_source_directory  # noqa: E402
from qomni.fmu.export import export_plant_fmu  # noqa: E402
from qomni.ident import kinematics  # noqa: E402
from qomni.datasheet import DataSheet  # noqa: E402
from qomni.ident.dynamics import forward_dynamics  # noqa: E402
from doubles import P_VALUES, identification, random_states  # noqa: E402

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")

SHEET = DataSheet.load()
G, I_G, TS = SHEET.geometry, SHEET.drive.i_G, SHEET.drive.cycle_time
EPS = 0.01
REF = R.PlantParameters(P_VALUES, G, I_G, EPS)
_D = ctypes.POINTER(ctypes.c_double)




@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    d = tmp_path_factory.mktemp("plant")
    return {v: export_plant_fmu(identification(), SHEET, d / f"plant{v}.fmu", v) for v in (2, 3)}


# --- one source of the equations: generated C == ident.dynamics.forward_dynamics ---------------------
@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    d = tmp_path_factory.mktemp("plantc")
    for name, text in codegen.generate_plant_c().files().items():
        (d / name).write_text(text)
    so = d / "libplant.so"
    subprocess.run(["gcc", "-std=c99", "-shared", "-fPIC", "-O2", "-Wall", "-Wextra", "-Werror",
                    str(d / "plant_generated.c"), "-o", str(so), "-lm"], check=True)
    return ctypes.CDLL(str(so))


def _arr(x):
    return np.ascontiguousarray(x, dtype=float).ctypes.data_as(_D)


@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_generated_forward_dynamics_equal_ident_on_random_states(lib, k):
    rng = np.random.default_rng(10 + k)
    n, nk = 200, kinematics.N_GENERALIZED[k]
    p = P_VALUES * rng.uniform(0.5, 1.5, 11)
    alpha, av, sd, _ = random_states(k, n, G, rng)  # a quarter of sd inside the tanh region
    u = rng.normal(0, 3, (n, 4))
    q = np.zeros((n, 9))
    q[:, 3:5] = alpha
    ref = forward_dynamics(k, q, sd, u, p, G, I_G, EPS, alpha_v=av if k == 2 else None)
    Href = kinematics.H(k, alpha, G, alpha_v=av if k == 2 else None)
    rhs = getattr(lib, f"qomni_plant_rhs_{k}")
    rhs.restype = None
    rhs.argtypes = [_D, ctypes.c_double, _D, _D, _D, _D, ctypes.c_double, ctypes.c_double, _D, _D]
    geo = np.array([G.l, G.b, G.a, G.r])
    worst = 0.0
    for j in range(n):
        sdd, qd, sd2 = np.zeros(2), np.zeros(9), np.zeros(2)
        sd2[:nk] = sd[j]
        rhs(_arr(alpha[j]), av[j], _arr(sd2), _arr(u[j]), _arr(p), _arr(geo), I_G, EPS,
            sdd.ctypes.data_as(_D), qd.ctypes.data_as(_D))
        worst = max(worst, np.max(np.abs(sdd[:nk] - ref[j])) / np.max(np.abs(ref[j])))
        np.testing.assert_allclose(qd, Href[j] @ sd[j], rtol=1e-12, atol=1e-14)
    assert worst <= 1e-9


def test_forward_dynamics_inverts_the_feedforward_law():
    """(21) then the forward dynamics give back s_ddot (modes with a full-rank H_k^T B)."""
    from qomni.ident.dynamics import feedforward

    rng = np.random.default_rng(3)
    for k in (1, 2, 3, 4):
        nk = kinematics.N_GENERALIZED[k]
        q = np.zeros((20, 9))
        q[:, 3:5] = kinematics.f_icr(rng.uniform(-0.5, 0.5, 20), G) if k == 2 else (
            rng.uniform(-1, 1, (20, 2)) if k == 1 else kinematics.mode_alpha(k, G))
        sd, sdd = rng.normal(0, 1, (20, nk)), rng.normal(0, 2, (20, nk))
        u = feedforward(k, q, sd, sdd, P_VALUES, G, I_G, EPS)
        np.testing.assert_allclose(forward_dynamics(k, q, sd, u, P_VALUES, G, I_G, EPS), sdd, rtol=1e-9, atol=1e-9)


# --- the FMU: validation and model description ----------------------------------------------------
@pytest.mark.parametrize("version", [2, 3])
def test_fmpy_validation_and_model_description(fmus, version):
    assert validate_fmu(str(fmus[version])) == []
    md = read_model_description(str(fmus[version]))
    cs = md.coSimulation
    assert cs.canHandleVariableCommunicationStepSize and cs.canGetAndSetFMUstate and cs.canSerializeFMUstate
    v = {x.name: x for x in md.modelVariables}
    for name in ("C_l", "B_w", "l", "b", "a", "r", "i_G", "eps", "steering_limit", "mode_tol", "omega_rest",
                 "max_step"):
        assert v[name].causality == "parameter" and v[name].variability == "tunable" and v[name].description
    assert v["m_ch"].unit == "kg" and v["eps"].unit == "rad/s" and v["max_step"].unit == "s"
    for name in ("x0", "y0", "gamma0", "alpha_l0", "alpha_r0", "x_ch_dot0", "gamma_ch_dot0"):
        assert v[name].causality == "parameter" and v[name].variability == "fixed"
    assert all(v[n].causality == "input" and v[n].unit == "N.m" for n in MOTOR_TORQUE)
    for name, unit in (("x_w", "m"), ("gamma_ch", "rad"), ("x_ch_dot", "m/s"), ("gamma_ch_dot", "rad/s"),
                       ("alpha_l_dot", "rad/s"), ("motor_position.fl", "rad"), ("motor_velocity.rr", "rad/s")):
        assert v[name].causality == "output" and v[name].unit == unit
    assert v["k"].causality == "output" and v["k_configuration"].causality == "output"
    outputs = [u.variable.name for u in md.outputs]
    assert len(outputs) == 20 and all(u.dependencies == [] for u in md.outputs)  # no direct feedthrough
    assert "plant" in md.description and "absorbed" in md.description


# --- hybrid behaviour: FMU == numpy reference -----------------------------------------------------------
def _run(path, alpha0, torque, duration, reference=True, start_values=None):
    vehicle = PlantVehicle(path, TS, {"alpha_l0": alpha0[0], "alpha_r0": alpha0[1], **(start_values or {})})
    state = R.initial_state(REF, alpha0=alpha0)
    worst, t, ks = 0.0, 0.0, []
    for _ in range(round(duration / TS)):
        u = np.asarray(torque(t), dtype=float)
        vehicle.exchange(u)
        t += TS
        out = vehicle.outputs()
        ks.append(out["k"])
        if reference:
            state = R.step(state, u, REF, TS)
            ref = R.outputs(state, REF)
            assert out["k"] == ref["k"] and out["k_configuration"] == ref["k_configuration"]
            for key in ("pose", "velocity", "alpha", "alpha_dot", "motor_position", "motor_velocity"):
                worst = max(worst, np.max(np.abs(out[key] - ref[key])))
    vehicle.close()
    return out, worst, ks


def _steer(side_torque):
    """Motor torques whose H_1^T B u = i_G a/r (u_rl - u_fl, u_fr - u_rr) steers each side."""
    return np.array([-side_torque[0], side_torque[0], side_torque[1], -side_torque[1]]) / 2


@pytest.mark.parametrize("version", [2, 3])
def test_steering_at_rest_in_mode_2_configuration(fmus, version):
    out, worst, ks = _run(fmus[version], (0.0, 0.0), lambda t: _steer((1.6, -2.4)), 0.3)
    assert worst < 1e-9 and set(ks) == {1}
    assert out["alpha"][0] > 0.2 and out["alpha"][1] < -0.1 and np.all(out["pose"] == 0)
    assert np.all(out["velocity"] == 0) and np.any(out["motor_position"] != 0)  # wheels swing about the axes


def test_straight_then_stop_and_steered_motion(fmus):
    def torque(t):  # drive, brake, then a torque below break-away (|tau_c| = 40 N < F_c = 159 N)
        return np.full(4, 2.0 if t < 0.2 else (-3.0 if t < 0.3 else -0.04))

    out, worst, ks = _run(fmus[2], (0.0, 0.0), torque, 0.5)
    assert worst < 1e-9 and ks[0] == 2 and ks[-1] == 1  # drives, brakes, comes to rest (stiction)
    assert out["pose"][0] > 0.02 and abs(out["pose"][1]) < 1e-12 and np.all(out["velocity"] == 0)
    a2 = kinematics.f_icr(0.3, G)[0]
    out, worst, ks = _run(fmus[3], a2, lambda t: np.full(4, 1.5), 0.3)
    assert worst < 1e-9 and set(ks) == {2}
    v = out["velocity"]
    assert v[2] == pytest.approx(v[0] * 2 * np.tan(0.3) / G.l, rel=1e-9)  # ICR held at (0, (l/2)/tan av)
    np.testing.assert_allclose(out["alpha"], a2, atol=1e-12)


def test_rotation_and_lateral_motion(fmus):
    m4, m3 = kinematics.mode_alpha(4, G), kinematics.mode_alpha(3, G)
    out, worst, ks = _run(fmus[2], m4, lambda t: np.array([1.0, 1.0, -1.0, -1.0]), 0.3)
    assert worst < 1e-9 and set(ks) == {4} and out["velocity"][2] < -0.3 and np.all(out["pose"][:2] == 0)
    # lateral: the right side presses into its stop and takes the drive
    out, worst, ks = _run(fmus[3], m3, lambda t: np.array([0.0, 0.0, 1.6, -1.6]), 0.3)
    assert worst < 1e-9 and set(ks) == {3} and out["velocity"][1] > 0.1
    np.testing.assert_array_equal(out["alpha"], m3)
    # the pseudo-inverse split pulls the left side off its stop: it steers, the chassis stays
    out, worst, ks = _run(fmus[3], m3, lambda t: np.array([-0.8, 0.8, 0.8, -0.8]), 0.3)
    assert worst < 1e-9 and set(ks) == {1} and out["alpha"][0] > m3[0] + 0.1 and out["alpha"][1] == m3[1]
    assert np.all(out["pose"] == 0)


def test_constraint_violating_torques_are_absorbed_while_moving(fmus):
    """Driving in mode 2 with steering torques off the ICR: the mode stays, alpha stays on f_ICR."""
    def torque(t):
        return np.full(4, 2.0) + (_steer((3.0, -3.0)) if t > 0.1 else 0.0)
    out, worst, ks = _run(fmus[2], (0.0, 0.0), torque, 0.25)
    assert worst < 1e-9 and set(ks) == {2}
    assert kinematics.icr_residual(out["alpha"], G)[0] < 1e-12


def test_steering_stops_hold(fmus):
    out, _, ks = _run(fmus[2], (1.4, -1.4), lambda t: _steer((4.0, -4.0)), 0.4, reference=False)
    np.testing.assert_allclose(out["alpha"], [np.pi / 2, -np.pi / 2], atol=0)
    assert np.all(out["alpha_dot"] == 0) and set(ks) == {1}


# --- FMI features ------------------------------------------------------------------------------------
@pytest.mark.parametrize("version", [2, 3])
def test_variable_step_size_and_large_steps_are_stable(fmus, version):
    steps = [0.002] * 100
    mixed = [0.0005, 0.0031, 0.0007, 0.013, 0.002, 0.0107, 0.0001] * 6
    mixed.append(0.2 - sum(mixed))
    results = []
    for sizes in (steps, mixed, [0.2], [0.05] * 4):
        with FmuSlave(fmus[version], {"eps": 1e-4}) as s:  # 100x sharper friction: sub-steps adapt
            s.set_real(s.refs(MOTOR_TORQUE), [2.0, 2.0, 2.0, 2.0])
            for h in sizes:
                s.step(h)
            assert s.time == pytest.approx(0.2)
            results.append(s.get_real(s.refs(["x_w", "x_ch_dot", "motor_position.fl"])))
    for r in results[1:]:
        np.testing.assert_allclose(r, results[0], rtol=1e-6)
    assert results[0][1] > 0.2


@pytest.mark.parametrize("version", [2, 3])
def test_fmu_state_get_set_serialize(fmus, version):
    with FmuSlave(fmus[version], {"alpha_l0": 0.0}) as s:
        api = s.fmu
        get_state = api.getFMUstate if version == 2 else api.getFMUState
        set_state = api.setFMUstate if version == 2 else api.setFMUState
        serialize = api.serializeFMUstate if version == 2 else api.serializeFMUState
        deserialize = api.deSerializeFMUstate if version == 2 else api.deserializeFMUState
        u, y = s.refs(MOTOR_TORQUE), s.refs(["x_w", "x_ch_dot", "motor_position.rr"])
        s.set_real(u, [2.0] * 4)
        s.step(0.1)
        state, t0 = get_state(), s.time
        blob = serialize(state)
        s.step(0.1)
        after = s.get_real(y)
        set_state(state)
        s.time = t0
        np.testing.assert_array_equal(s.get_real(y), s.get_real(y))
        s.step(0.1)
        np.testing.assert_array_equal(s.get_real(y), after)
        set_state(deserialize(blob))
        s.time = t0
        s.step(0.1)
        np.testing.assert_array_equal(s.get_real(y), after)


def test_initial_state_parameters(fmus):
    g4 = kinematics.mode_alpha(4, G)
    start = {"x0": 1.0, "y0": -2.0, "gamma0": 0.5, "alpha_l0": g4[0], "alpha_r0": g4[1], "gamma_ch_dot0": 0.4}
    vehicle = PlantVehicle(fmus[3], TS, start)
    out = vehicle.outputs()
    np.testing.assert_allclose(out["pose"], [1.0, -2.0, 0.5])
    assert out["k"] == 4 and out["velocity"][2] == pytest.approx(0.4)
    vehicle.close()
    state = R.initial_state(REF, (1.0, -2.0, 0.5), g4, (0, 0, 0.4, 0, 0))
    assert state[R.K] == 4


@pytest.mark.parametrize("version", [2, 3])
def test_bad_input_and_initial_state_are_errors(fmus, version, capsys, tmp_path, monkeypatch):
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))   # where the slaves extract their FMU
    with FmuSlave(fmus[version]) as s:
        with pytest.raises(FMICallException):
            s.set_real(s.refs(MOTOR_TORQUE), [np.nan, 0, 0, 0])
    assert "input motor_torque.fl is not finite" in capsys.readouterr().out
    with pytest.raises(FMICallException):
        FmuSlave(fmus[version], {"alpha_l0": 2.0})
    assert "within the stops" in capsys.readouterr().out
    with pytest.raises(FMICallException):
        FmuSlave(fmus[version], {"alpha_l0": 0.3, "x_ch_dot0": 0.5})
    assert "configuration" in capsys.readouterr().out
    assert list(tmp_path.iterdir()) == []          # a refused instance leaves no extracted FMU behind


@pytest.mark.skipif(shutil.which("cmake") is None, reason="needs cmake")
def test_fmpy_rebuilds_the_plant_from_its_sources(fmus, tmp_path):
    from fmpy import extract
    from fmpy.build import build_platform_binary

    d = tmp_path / "fmu"
    extract(str(fmus[3]), str(d))
    shutil.rmtree(d / "binaries")
    (tmp_path / "build").mkdir()
    build_platform_binary(d, build_dir=tmp_path / "build")
    with FmuSlave(d) as s:
        s.set_real(s.refs(MOTOR_TORQUE), [2.0] * 4)
        s.step(0.1)
        assert s.get_real(s.refs(["x_ch_dot"]))[0] > 0


def test_c_sources_are_packaged(fmus):
    import zipfile

    names = set(zipfile.ZipFile(fmus[2]).namelist())
    assert {"sources/plant.c", "sources/plant.h", "sources/model.c", "sources/plant_generated.c",
            "sources/config.h", "binaries/linux64/plant2.so"} <= names
    assert (c_source_directory() / "plant" / "plant.c").exists()
