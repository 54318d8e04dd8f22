"""The identified covariance as SSP parameter sets (fmu.parameter_sets): the archive passes fmpy's SSP
reader with XSD validation (SSD and every SSV), the sets carry the FMU's parameter names and units, their
statistics are those of the covariance, every set is admissible and runs in the plant FMU."""
import dataclasses
import shutil

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
pytest.importorskip("lxml")
from fmpy import read_model_description  # noqa: E402
from fmpy.ssp.ssd import read_ssd, read_ssv  # noqa: E402

from qomni.conventions import P1_NAMES, PARAMETER_NAMES  # noqa: E402
from qomni.datasheet import DataSheet  # noqa: E402
from qomni.fmu.cosim import MOTOR_TORQUE, FmuSlave  # noqa: E402
from qomni.fmu.export import export_plant_fmu  # noqa: E402
from qomni.fmu.parameter_sets import (ParameterSetError, read_parameter_sets, sample_name,  # noqa: E402
                                      sample_parameters, write_parameter_sets)
from doubles import identification  # noqa: E402

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
N = 400


def _with_covariance(relative_std, seed=0):
    """The test identification with a correlated covariance: std = relative_std * value, correlations of a
    random positive definite matrix (some strong, as (23)'s regressor makes them)."""
    ident = identification()
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(10, 10)) + 2.0 * np.eye(10)
    c = a @ a.T
    corr = c / np.sqrt(np.outer(np.diag(c), np.diag(c)))
    std = np.array([relative_std * ident.values[n] for n in P1_NAMES])
    return dataclasses.replace(ident, covariance=corr * np.outer(std, std)), std, corr


@pytest.fixture(scope="session")
def archive(tmp_path_factory):
    d = tmp_path_factory.mktemp("ssp")
    ident, std, corr = _with_covariance(0.05)
    fmu = export_plant_fmu(ident, DataSheet.load(), d / "qomni_plant.fmu", 3)
    return write_parameter_sets(ident, fmu, d / "plant_uncertainty.ssp", n=N, seed=1), ident, std, corr, fmu


def test_the_archive_loads_in_fmpys_ssp_reader_with_validation(archive):
    path, ident, *_ = archive
    ssd = read_ssd(str(path), validate=True)  # SystemStructureDescription.xsd; the bound SSV too
    [component] = ssd.system.elements
    [binding] = component.parameterBindings
    nominal = {p.name: float(p.value) for p in binding.parameterValues[0].parameters}
    assert component.source == "resources/qomni_plant.fmu"
    assert nominal == {**{n: ident.values[n] for n in P1_NAMES}, "B_w": ident.B_w}
    _, samples = read_parameter_sets(path)
    for i in (0, N // 2, N - 1):  # SystemStructureParameterValues.xsd
        ssv = read_ssv(str(path), resource=sample_name(i), validate=True)
        assert [float(p.value) for p in ssv.parameters] == list(samples[i])


def test_sets_name_the_fmus_parameters_with_its_units(archive):
    path, *_, fmu = archive
    units = {v.name: v.unit for v in read_model_description(str(fmu)).modelVariables}
    ssv = read_ssv(str(path), resource=sample_name(0), validate=True)
    assert [p.name for p in ssv.parameters] == list(PARAMETER_NAMES)
    assert all(p.unit == units[p.name] for p in ssv.parameters)


def test_the_samples_have_the_identified_mean_and_covariance(archive):
    """Mean within 4 standard errors; correlations within 4 standard errors (1 - rho^2) / sqrt(N)."""
    path, ident, std, corr, _ = archive
    _, samples = read_parameter_sets(path)
    assert samples.shape == (N, 11) and np.all(samples[:, 10] == ident.B_w)
    mean = np.array([ident.values[n] for n in P1_NAMES])
    assert np.all(np.abs(samples[:, :10].mean(axis=0) - mean) <= 4 * std / np.sqrt(N))
    sample_corr = np.corrcoef(samples[:, :10].T)
    assert np.all(np.abs(sample_corr - corr) <= 4 * (1 - corr**2) / np.sqrt(N) + 1e-12)
    np.testing.assert_allclose(samples[:, :10].std(axis=0, ddof=1), std, rtol=4 / np.sqrt(2 * N))


def test_a_sampled_set_runs_in_the_plant_fmu(archive):
    path, *_, fmu = archive
    nominal, samples = read_parameter_sets(path)
    ends = []
    for values in (nominal, dict(zip(PARAMETER_NAMES, samples[0]))):
        with FmuSlave(fmu, values) as s:
            s.set_real(s.refs(MOTOR_TORQUE), [2.0] * 4)
            for _ in range(25):
                s.step(0.004)
            ends.append(s.get_real(s.refs(["x_w"]))[0])
    assert ends[0] > 0 and ends[1] > 0 and ends[0] != ends[1]


def test_wide_uncertainty_is_truncated_to_admissible_parameters():
    ident, *_ = _with_covariance(0.6, seed=3)
    samples, rejected = sample_parameters(ident, 200, seed=2)
    assert rejected > 0 and np.all(samples >= 0)
    assert np.all(samples[:, [PARAMETER_NAMES.index(n) for n in ("C_l", "C_r", "m_ch", "C_ch")]] > 0)


def test_no_covariance_is_an_error(tmp_path):
    with pytest.raises(ParameterSetError, match="no covariance"):
        sample_parameters(identification(), 10)


def test_the_cli_writes_the_archive_beside_the_fmu_and_refuses_a_run_without_covariance(tmp_path):
    import json

    from typer.testing import CliRunner

    from qomni.cli import app
    from pathlib import Path

    import qomni

    DEFAULT_PATH = Path(qomni.__file__).parent / "data" / "prototype_datasheet.toml"
    ident, *_ = _with_covariance(0.05)
    (tmp_path / "with").mkdir()
    (tmp_path / "with" / "identification.json").write_text(json.dumps(ident.to_json_dict()))
    runner = CliRunner()
    result = runner.invoke(app, ["export-fmu", str(tmp_path / "with"), "--out", str(tmp_path / "p.fmu"), "--kind",
                                 "plant", "--vehicle", str(DEFAULT_PATH), "--parameter-sets", "3"])
    assert result.exit_code == 0, result.output
    assert read_parameter_sets(tmp_path / "p.ssp")[1].shape == (3, 11)
    (tmp_path / "without").mkdir()
    (tmp_path / "without" / "identification.json").write_text(json.dumps(identification().to_json_dict()))
    result = runner.invoke(app, ["export-fmu", str(tmp_path / "without"), "--out", str(tmp_path / "q.fmu"),
                                 "--kind", "plant", "--vehicle", str(DEFAULT_PATH), "--parameter-sets", "3"])
    assert result.exit_code == 2 and "no covariance" in result.output and "Traceback" not in result.output
