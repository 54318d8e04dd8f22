"""Data sheet loading."""
import tomllib
from dataclasses import asdict, fields
from pathlib import Path

import pytest

from qomni.datasheet import DataSheet, DataSheetError, Nominal
from qomni.ident.symbolic import PARAMETER_NAMES

ROOT = Path(__file__).resolve().parents[1]
EMULATOR_TOML = ROOT / "emulator" / "data" / "prototype.toml"
OWN_TOML = ROOT / "qomni" / "data" / "prototype_datasheet.toml"


def test_packaged_copy_equals_emulator_description():
    emu = tomllib.loads(EMULATOR_TOML.read_text())
    own = tomllib.loads(OWN_TOML.read_text())
    assert set(own) == {"vehicle", "geometry", "drive", "nominal"}
    for section in own:
        assert own[section] == emu[section], section
    sheet = DataSheet.load()
    assert sheet.name == "prototype"
    assert asdict(sheet.geometry) == emu["geometry"]
    assert asdict(sheet.drive) == emu["drive"]
    assert asdict(sheet.nominal) == emu["nominal"]


def test_emulator_description_loads_and_truth_is_ignored():
    sheet = DataSheet.load(EMULATOR_TOML)
    default = DataSheet.load()
    assert (sheet.geometry, sheet.drive, sheet.nominal) == (default.geometry, default.drive, default.nominal)
    assert sheet.source == str(EMULATOR_TOML)
    assert not hasattr(sheet, "truth")


def test_nominal_order_is_p():
    assert tuple(f.name for f in fields(Nominal)) == PARAMETER_NAMES
    assert DataSheet.load().nominal.p.shape == (11,)


def _write(tmp_path, text):
    path = tmp_path / "sheet.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("old,new,pattern", [
    ("[nominal]", "[nominalx]", r"missing section \[nominal\]"),
    ("r = 0.10 ", "# r = 0.10 ", r"\[geometry\] is missing key 'r'"),
    ("cycle_time = 0.002", "cycle_time = \"2 ms\"", r"\[drive\] key 'cycle_time' must be a number"),
    ("a = 0.08 ", "a = 0.5 ", r"\[geometry\] key 'a' must be in"),
    ("a = 0.08 ", "a = 0.0 ", r"\[geometry\] key 'a' must be in \(0, b/2\): the wheels steer .* no lever"),
    ("encoder_increments = 65536", "encoder_increments = 65536.5", r"\[drive\] key 'encoder_increments'"),
    ("d_cw = 4.0", "d_cw = -1.0", r"\[nominal\] key 'd_cw' must be >= 0"),
    ("m_ch = 800.0", "m_ch = 800.0\nm_total = 1.0", r"\[nominal\] has unknown keys \['m_total'\]"),
    ("max_torque = 6.0", "max_torque = 1.0", r"\[drive\] key 'max_torque'"),
    ("\n[drive]\n", "\n[drive\n", "not valid TOML"),
])
def test_errors_name_file_section_key(tmp_path, old, new, pattern):
    path = _write(tmp_path, OWN_TOML.read_text().replace(old, new, 1))
    with pytest.raises(DataSheetError, match=pattern) as info:
        DataSheet.load(path)
    assert str(path) in str(info.value)


def test_missing_file():
    with pytest.raises(FileNotFoundError):
        DataSheet.load("/nonexistent/sheet.toml")
