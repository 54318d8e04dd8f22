"""Native FMI 2.0 / 3.0 Co-Simulation FMUs of the feed-forward law (21) (fmu.export): validation,
simulation with fmpy against ident.dynamics.feedforward, FMU state, the FMI API surface, error handling
and rebuilding from the shipped sources."""
import ctypes
import json
import re
import shutil
import zipfile

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
from fmpy import read_model_description, simulate_fmu  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402
from fmpy.fmi3 import FMU3Slave  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

from qomni.fmu.build import c_source_directory  # noqa: E402
from qomni.fmu.export import export_feedforward_fmu  # noqa: E402
from qomni.ident import kinematics  # noqa: E402
from qomni.datasheet import DataSheet  # noqa: E402
from qomni.ident.dynamics import feedforward  # noqa: E402
from qomni.conventions import P1_NAMES  # noqa: E402
from qomni.ident.result import IdentificationResult  # noqa: E402
from qomni.ident.symbolic import COORDINATE_NAMES, PARAMETER_NAMES, WHEELS  # noqa: E402

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")

RTOL = 1e-9
SHEET = DataSheet.load()
EPS = 0.01
IDENTIFIED = dict(C_l=0.3342, d_vl=4.4649, d_cl=12.9458, C_r=0.4501, d_vr=2.4820, d_cr=17.1071,
                  m_ch=842.0684, C_ch=286.5955, d_vw=0.7316, d_cw=3.9656)
B_W = 0.121
P = np.array([IDENTIFIED[n] for n in P1_NAMES] + [B_W])
Q_NAMES = [f"q.{n}" for n in COORDINATE_NAMES]
SD_NAMES, SDD_NAMES = ["s_dot[1]", "s_dot[2]"], ["s_ddot[1]", "s_ddot[2]"]
OUTPUTS = [f"motor_torque.{w}" for w in WHEELS]
N_K = {1: 2, 2: 2, 3: 1, 4: 1}


def identification() -> IdentificationResult:
    return IdentificationResult(values=dict(IDENTIFIED), std={n: 0.01 * abs(v) for n, v in IDENTIFIED.items()},
                                B_w=B_W, condition_number=12.3, rows_used={}, rows_total={}, residual_rms={})


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    d = tmp_path_factory.mktemp("fmus")
    return {2: export_feedforward_fmu(identification(), SHEET, d / "ff2.fmu", 2),
            3: export_feedforward_fmu(identification(), SHEET, d / "ff3.fmu", 3)}


@pytest.fixture(scope="module")
def unzipped(fmus, tmp_path_factory):
    out = {}
    for v, path in fmus.items():
        d = tmp_path_factory.mktemp(f"unzipped{v}")
        with zipfile.ZipFile(path) as zf:
            zf.extractall(d)
        out[v] = d
    return out


def reference(k, q, sd, sdd):
    """ident.dynamics.feedforward on rows of recorded inputs (all of mode k)."""
    nk = N_K[k]
    return feedforward(k, q, sd[:, :nk], sdd[:, :nk], P, SHEET.geometry, SHEET.drive.i_G, EPS)


def relative_error(u, ref):
    return np.max(np.abs(u - ref), axis=-1) / np.maximum(np.max(np.abs(ref), axis=-1), 1e-300)


def random_block(k, n, rng):
    """n random desired states of mode k as rows (q (n, 9), sd (n, 2), sdd (n, 2))."""
    g = SHEET.geometry
    q = rng.normal(0, 3, (n, 9))
    if k == 1:
        q[:, 3:5] = rng.uniform(-1.5, 1.5, (n, 2))
    elif k == 2:
        q[:, 3:5] = kinematics.f_icr(rng.uniform(-0.9, 0.9, n) * kinematics.alpha_v_max(g), g)
    else:
        q[:, 3:5] = kinematics.mode_alpha(k, g)
    sd, sdd = rng.normal(0, 1, (n, 2)), rng.normal(0, 3, (n, 2))
    sd[: n // 4] *= 0.01
    return q, sd, sdd


# --- validation and model description ---------------------------------------------------------------
@pytest.mark.parametrize("version", [2, 3])
def test_fmpy_validation_reports_no_problems(fmus, version):
    assert validate_fmu(str(fmus[version])) == []


@pytest.mark.parametrize("version", [2, 3])
def test_model_description(fmus, version):
    md = read_model_description(str(fmus[version]))
    assert md.fmiVersion == f"{version}.0" and md.coSimulation.modelIdentifier == f"ff{version}"
    assert md.coSimulation.canHandleVariableCommunicationStepSize
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
    by_name = {v.name: v for v in md.modelVariables}
    for name, value in zip(PARAMETER_NAMES, P):
        v = by_name[name]
        assert (v.causality, v.variability) == ("parameter", "tunable") and float(v.start) == value
    for name, value in (("l", 1.2), ("b", 0.9), ("a", 0.08), ("r", 0.1), ("i_G", 25.0), ("eps", EPS)):
        assert float(by_name[name].start) == value and by_name[name].variability == "tunable"
    assert by_name["k"].type == ("Integer" if version == 2 else "Int32") and by_name["k"].causality == "input"
    assert all(by_name[n].causality == "input" for n in Q_NAMES + SD_NAMES + SDD_NAMES)
    assert all(by_name[n].causality == "output" and by_name[n].unit == "N.m" for n in OUTPUTS)
    assert by_name["m_ch"].unit == "kg" and by_name["q.alpha_l"].unit == "rad"
    assert md.defaultExperiment.stepSize == "0.002"
    # outputs depend on k, alpha_l, alpha_r, s_dot, s_ddot, alpha_v (FMI 2: 1-based indices; FMI 3: VRs)
    deps = {n: by_name[n] for n in ("k", "q.alpha_l", "q.alpha_r", *SD_NAMES, *SDD_NAMES, "alpha_v")}
    assert [u.variable.name for u in md.outputs] == OUTPUTS
    for u in md.outputs:
        assert set(d.name for d in u.dependencies) == set(deps)
    with zipfile.ZipFile(fmus[version]) as zf:
        names = set(zf.namelist())
        xml = zf.read("modelDescription.xml").decode()
    binary = f"binaries/{'linux64' if version == 2 else 'x86_64-linux'}/ff{version}.so"
    assert binary in names
    assert {f"sources/{n}" for n in ("fmu_instance.c", "model.c", "feedforward.c", "feedforward_generated.c",
                                      "config.h", f"fmi{version}Functions.c", f"fmi{version}Functions.h")} <= names
    if version == 2:
        first_output = next(i for i, v in enumerate(md.modelVariables) if v.name == OUTPUTS[0]) + 1
        assert f'<Unknown index="{first_output}" dependencies=' in xml
        assert {f.split("/")[-1] for f in names if f.endswith(".c")} == set(
            md.buildConfigurations[0].sourceFileSets[0].sourceFiles)
    else:
        assert "sources/buildDescription.xml" in names
        assert f'<Output valueReference="{by_name[OUTPUTS[0]].valueReference}" dependencies=' in xml


def test_export_from_identification_json_and_deterministic_token(tmp_path):
    path = tmp_path / "identification.json"
    path.write_text(json.dumps(identification().to_json_dict()))
    a = export_feedforward_fmu(tmp_path, SHEET, tmp_path / "a.fmu", 2, model_identifier="ff")
    b = export_feedforward_fmu(path, SHEET, tmp_path / "b.fmu", 2, model_identifier="ff")
    ma, mb = read_model_description(str(a)), read_model_description(str(b))
    assert ma.guid == mb.guid and re.fullmatch(r"\{[0-9a-f-]{36}\}", ma.guid)
    with pytest.raises(ValueError):
        export_feedforward_fmu(path, SHEET, tmp_path / "c.zip", 2)
    with pytest.raises(ValueError):
        export_feedforward_fmu(path, SHEET, tmp_path / "c.fmu", 4)


@pytest.mark.parametrize("version", [2, 3])
def test_every_fmi_function_is_exported(unzipped, version):
    header = (c_source_directory() / "include" / f"fmi{version}Functions.h").read_text()
    names = re.findall(rf"FMI{version}_Export\s+fmi{version}\w+TYPE\s+(fmi{version}\w+);", header)
    assert len(names) == {2: 44, 3: 75}[version]
    so = next((unzipped[version] / "binaries").rglob("*.so"))
    lib = ctypes.CDLL(str(so))
    assert [n for n in names if not hasattr(lib, n)] == []
    assert not hasattr(lib, "fmu_get_float64")  # internal symbols stay hidden


# --- simulation against ident.dynamics.feedforward ----------------------------------------------------
@pytest.mark.parametrize("version", [2, 3])
def test_simulation_equals_ident_feedforward_for_every_mode(fmus, version):
    rng = np.random.default_rng(version)
    n, h = 50, 0.002
    blocks = [(k, *random_block(k, n, rng)) for k in (1, 2, 3, 4)]
    names = ["k", *Q_NAMES, *SD_NAMES, *SDD_NAMES, "alpha_v"]  # alpha_v unused (use_alpha_v_input false)
    dtype = [("time", np.float64), ("k", np.int32)] + [(c, np.float64) for c in names[1:]]
    signal = np.zeros(4 * n, dtype=dtype)
    signal["time"] = np.arange(4 * n) * h
    signal["k"] = np.repeat([1, 2, 3, 4], n)
    for j, c in enumerate(Q_NAMES):
        signal[c] = np.concatenate([b[1][:, j] for b in blocks])
    for j in range(2):
        signal[SD_NAMES[j]] = np.concatenate([b[2][:, j] for b in blocks])
        signal[SDD_NAMES[j]] = np.concatenate([b[3][:, j] for b in blocks])
    result = simulate_fmu(str(fmus[version]), input=signal, output=names + OUTPUTS, step_size=h,
                          output_interval=h, stop_time=(4 * n - 1) * h)
    assert len(result) == 4 * n
    q = np.stack([result[c] for c in Q_NAMES], axis=1)
    sd = np.stack([result[c] for c in SD_NAMES], axis=1)
    sdd = np.stack([result[c] for c in SDD_NAMES], axis=1)
    u = np.stack([result[c] for c in OUTPUTS], axis=1)
    # the inputs the FMU saw are the designed samples (shifted by one communication step)
    np.testing.assert_allclose(q[1:], np.stack([signal[c] for c in Q_NAMES], axis=1)[:-1], rtol=1e-12)
    worst = 0.0
    for k in (1, 2, 3, 4):
        rows = result["k"] == k
        assert rows.sum() >= n - 1
        err = relative_error(u[rows], reference(k, q[rows], sd[rows], sdd[rows]))
        worst = max(worst, err.max())
    assert worst <= RTOL


def _slave(unzipped, version, **kwargs):
    md = read_model_description(str(unzipped[version]))
    cls = FMU2Slave if version == 2 else FMU3Slave
    fmu = cls(guid=kwargs.pop("guid", md.guid), unzipDirectory=str(unzipped[version]),
              modelIdentifier=md.coSimulation.modelIdentifier, instanceName="ff")
    vr = {v.name: v.valueReference for v in md.modelVariables}
    return fmu, vr


class Api:
    """Version-neutral access to an FMU2Slave / FMU3Slave."""

    def __init__(self, fmu, vr, version):
        self.fmu, self.vr, self.v = fmu, vr, version

    def start(self):
        self.fmu.instantiate()
        if self.v == 2:
            self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()
        return self

    def set(self, k=None, q=None, sd=None, sdd=None, **real):
        if k is not None:
            (self.fmu.setInteger if self.v == 2 else self.fmu.setInt32)([self.vr["k"]], [int(k)])
        pairs = list(real.items())
        for names, values in ((Q_NAMES, q), (SD_NAMES, sd), (SDD_NAMES, sdd)):
            if values is not None:
                pairs += list(zip(names, values))
        if pairs:
            refs, vals = [self.vr[n] for n, _ in pairs], [float(x) for _, x in pairs]
            (self.fmu.setReal if self.v == 2 else self.fmu.setFloat64)(refs, vals)

    def get(self, names):
        return np.array((self.fmu.getReal if self.v == 2 else self.fmu.getFloat64)([self.vr[n] for n in names]))

    def step(self, t, h):
        self.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)

    def get_state(self):
        return self.fmu.getFMUstate() if self.v == 2 else self.fmu.getFMUState()

    def set_state(self, s):
        return self.fmu.setFMUstate(s) if self.v == 2 else self.fmu.setFMUState(s)

    def free_state(self, s):
        return self.fmu.freeFMUstate(s) if self.v == 2 else self.fmu.freeFMUState(s)

    def serialize(self, s):
        return self.fmu.serializeFMUstate(s) if self.v == 2 else self.fmu.serializeFMUState(s)

    def deserialize(self, b):
        return self.fmu.deSerializeFMUstate(b) if self.v == 2 else self.fmu.deserializeFMUState(b)

    def close(self):
        self.fmu.terminate()
        self.fmu.freeInstance()


@pytest.mark.parametrize("version", [2, 3])
def test_mode_2_with_alpha_v_input_and_tunable_parameters(unzipped, version):
    api = Api(*_slave(unzipped, version), version).start()
    rng = np.random.default_rng(11)
    g = SHEET.geometry
    api.fmu.setBoolean([api.vr["use_alpha_v_input"]], [True])
    for av in rng.uniform(-0.9, 0.9, 5) * kinematics.alpha_v_max(g):
        q, sd, sdd = random_block(1, 1, rng)  # alpha of q is ignored: alpha = f_ICR(alpha_v)
        api.set(k=2, q=q[0], sd=sd[0], sdd=sdd[0], alpha_v=av)
        qq = q.copy()
        qq[:, 3:5] = kinematics.f_icr(av, g)
        ref = feedforward(2, qq, sd, sdd, P, g, SHEET.drive.i_G, EPS, alpha_v=av)
        assert relative_error(api.get(OUTPUTS), ref[0]) <= RTOL
    # tunable parameter changed in Step Mode
    api.fmu.setBoolean([api.vr["use_alpha_v_input"]], [False])
    q, sd, sdd = random_block(4, 1, rng)
    api.set(k=4, q=q[0], sd=sd[0], sdd=sdd[0], m_ch=1000.0, C_ch=300.0)
    p = P.copy()
    p[PARAMETER_NAMES.index("m_ch")], p[PARAMETER_NAMES.index("C_ch")] = 1000.0, 300.0
    ref = feedforward(4, q, sd[:, :1], sdd[:, :1], p, g, SHEET.drive.i_G, EPS)
    assert relative_error(api.get(OUTPUTS), ref[0]) <= RTOL
    api.close()


# --- FMU state, variable step size, errors ------------------------------------------------------------
@pytest.mark.parametrize("version", [2, 3])
def test_fmu_state_get_set_and_serialize_round_trip(unzipped, version):
    api = Api(*_slave(unzipped, version), version).start()
    rng = np.random.default_rng(5)
    qa, sda, sdda = random_block(1, 1, rng)
    api.set(k=1, q=qa[0], sd=sda[0], sdd=sdda[0])
    api.step(0.0, 0.01)
    ua, ta = api.get(OUTPUTS), api.get(["time"])[0]
    state = api.get_state()
    blob = api.serialize(state)
    qb, sdb, sddb = random_block(4, 1, rng)
    api.set(k=4, q=qb[0], sd=sdb[0], sdd=sddb[0])
    api.step(ta, 0.02)
    ub = api.get(OUTPUTS)
    assert not np.allclose(ua, ub)
    api.set_state(state)
    assert np.array_equal(api.get(OUTPUTS), ua) and api.get(["time"])[0] == ta
    api.set(k=4, q=qb[0], sd=sdb[0], sdd=sddb[0])
    restored = api.deserialize(blob)
    api.set_state(restored)
    assert np.array_equal(api.get(OUTPUTS), ua) and api.get(["time"])[0] == ta
    api.step(ta, 0.005)  # simulation continues from the restored time
    api.free_state(state)
    api.free_state(restored)
    api.close()


@pytest.mark.parametrize("version", [2, 3])
def test_variable_communication_step_size(unzipped, version, capsys):
    api = Api(*_slave(unzipped, version), version).start()
    t = 0.0
    for h in (0.002, 0.0007, 0.5, 1e-6, 0.013):
        api.step(t, h)
        t += h
        assert api.get(["time"])[0] == pytest.approx(t, rel=1e-15)
    with pytest.raises(FMICallException):
        api.step(t + 1.0, 0.002)  # not the current communication point
    with pytest.raises(FMICallException):
        api.step(t, 0.0)
    assert "currentCommunicationPoint" in capsys.readouterr().out
    api.close()


@pytest.mark.parametrize("version", [2, 3])
def test_invalid_mode_and_wrong_token_are_errors(unzipped, version, capsys):
    api = Api(*_slave(unzipped, version), version).start()
    api.set(k=7)
    with pytest.raises(FMICallException):
        api.get(OUTPUTS)
    assert "k must be 1, 2, 3 or 4" in capsys.readouterr().out
    with pytest.raises(FMICallException):  # outputs cannot be set
        api.set(**{OUTPUTS[0]: 1.0})
    api.set(k=1)
    assert np.all(np.isfinite(api.get(OUTPUTS)))
    api.close()
    fmu, _ = _slave(unzipped, version, guid="{00000000-0000-0000-0000-000000000000}")
    with pytest.raises(Exception, match="instantiate"):
        fmu.instantiate()
    assert "does not match" in capsys.readouterr().out


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("k", [1, 2, 3, 4])
@pytest.mark.parametrize("name, value", [("q.alpha_l", float("nan")), ("q.alpha_r", float("inf")),
                                         ("s_dot[2]", float("-inf")), ("q.beta_rr", float("nan"))])
def test_a_non_finite_input_is_an_error_in_every_mode(unzipped, version, capsys, k, name, value):
    """Modes 3 and 4 fix the steering angles and read no q.alpha_*: a NaN there is still an error, raised
    when it is set; the input keeps its value and the outputs stay finite."""
    api = Api(*_slave(unzipped, version), version).start()
    api.set(k=k)
    with pytest.raises(FMICallException):
        api.set(**{name: value})
    assert f"input {name} is not finite" in capsys.readouterr().out
    assert np.all(np.isfinite(api.get(OUTPUTS)))
    api.close()


# --- rebuild from the shipped sources ----------------------------------------------------------------
@pytest.mark.skipif(shutil.which("cmake") is None, reason="needs cmake")
@pytest.mark.parametrize("version", [2, 3])
def test_fmpy_rebuilds_the_binary_from_the_sources(unzipped, version, tmp_path):
    from fmpy.build import build_platform_binary

    d = tmp_path / "fmu"
    shutil.copytree(unzipped[version], d)
    shutil.rmtree(d / "binaries")
    (tmp_path / "build").mkdir()
    build_platform_binary(d, build_dir=tmp_path / "build")
    assert next((d / "binaries").rglob("*.so"))
    rng = np.random.default_rng(2)
    api = Api(*_slave({version: d}, version), version).start()
    q, sd, sdd = random_block(2, 1, rng)
    api.set(k=2, q=q[0], sd=sd[0], sdd=sdd[0])
    assert relative_error(api.get(OUTPUTS), reference(2, q, sd, sdd)[0]) <= RTOL
    api.close()
