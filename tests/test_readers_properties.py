"""Every reader, fed arbitrary input (hypothesis), either returns a valid, finite result or raises its
domain's one error type naming the file: never another exception, never a non-finite number."""
from __future__ import annotations

import copy
import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from qomni.datasheet import DataSheet, DataSheetError
from qomni.emulator.description import DescriptionError, VehicleDescription
from qomni.emulator.effects import EffectSet, EffectsError
from qomni.hil.device.faults import FaultPlan, FaultPlanError
from qomni.ident.recording import COLUMNS, RecordingError, read_signals
from qomni.conventions import P1_NAMES
from qomni.ident.rundir import (RunDirectoryError, completed_steps, datasheet_from_metadata,
                                      load_identification, read_json)

SETTINGS = settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
_numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**6, 10**6),
                     st.text(max_size=5), st.booleans(), st.lists(st.floats(), max_size=3))


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "").replace('"', "") + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return str(v)


def _mutated(text: str, key: str, value) -> str:
    return "\n".join(f"{key} = {_toml_value(value)}" if line.split("=")[0].strip() == key else line
                     for line in text.splitlines())


_SHEET_TEXT = (Path(__file__).resolve().parents[1] / "qomni" / "data" / "prototype_datasheet.toml").read_text()


@SETTINGS
@given(key=st.sampled_from(["l", "b", "a", "r", "i_G", "rated_torque", "max_torque", "cycle_time",
                            "encoder_increments", "m_ch", "C_ch", "d_vw", "B_w"]), value=_numbers)
def test_data_sheet_reader(key, value):
    try:
        sheet = DataSheet.loads(_mutated(_SHEET_TEXT, key, value), "sheet.toml")
    except DataSheetError as exc:
        assert "sheet.toml" in str(exc)
    else:
        assert all(math.isfinite(x) for x in (*sheet.nominal.p, sheet.drive.cycle_time, sheet.geometry.l))


@SETTINGS
@given(section=st.sampled_from(["truth", "body", "noise"]), value=_numbers, pick=st.integers(0, 10))
@example(section="body", value=1.3407807929942597e+154, pick=10)   # a chassis height whose square overflows
def test_vehicle_description_reader(tmp_path, section, value, pick):
    from importlib import resources

    text = resources.files("qomni.emulator").joinpath("data/prototype.toml").read_text()
    keys = list(tomllib.loads(text)[section])
    path = tmp_path / "v.toml"
    path.write_text(_mutated(text, keys[pick % len(keys)], value))
    try:
        desc = VehicleDescription.load(path)
    except DescriptionError as exc:
        assert str(path) in str(exc)
    else:
        assert desc.truth.m_ch > 0 and math.isfinite(desc.truth.C_ch)


_effect_tables = st.dictionaries(
    st.sampled_from(["payload", "incline", "stribeck", "actuator_delay", "backlash", "nonsense"]),
    st.dictionaries(st.sampled_from(["mass", "angle", "delay", "gap", "joints", "com_offset", "x"]), _numbers,
                    max_size=3), max_size=3)


@SETTINGS
@given(data=_effect_tables)
def test_effects_reader(data):
    try:
        EffectSet.from_dict(data, "e.toml")
    except EffectsError as exc:
        assert "e.toml" in str(exc)


@SETTINGS
@given(data=st.dictionaries(st.sampled_from(["seed", "frame_loss", "latency", "bus_off", "power_cycle", "x"]),
                            st.one_of(_numbers, st.dictionaries(st.sampled_from(["rate", "mean", "at", "node"]),
                                                                _numbers, max_size=2),
                                      st.lists(st.dictionaries(st.sampled_from(["at", "duration", "node", "off"]),
                                                               _numbers, max_size=4), max_size=2)), max_size=3))
def test_fault_plan_reader(data):
    try:
        plan = FaultPlan.from_dict(data, "f.toml")
    except FaultPlanError as exc:
        assert "f.toml" in str(exc)
    else:
        assert all(math.isfinite(w.at) for w in plan.bus_off + plan.sync_loss)


@SETTINGS
@given(body=st.binary(max_size=300))
def test_json_reader(tmp_path, body):
    path = tmp_path / "identification.json"
    path.write_bytes(body)
    with pytest.raises(RunDirectoryError, match="identification.json"):
        load_identification(path)                 # no random bytes make a complete identification


@SETTINGS
@given(rows=st.lists(st.lists(st.one_of(st.floats(allow_nan=True), st.text(max_size=4)), min_size=0,
                              max_size=len(COLUMNS) + 1), max_size=6))
def test_signals_reader(tmp_path, rows):
    from qomni.ident.recording import header

    path = tmp_path / "signals.csv"
    path.write_text("\n".join([",".join(header()), *(",".join(map(str, r)) for r in rows)]) + "\n")
    try:
        signals = read_signals(path)
    except RecordingError as exc:
        assert str(path) in str(exc)
    else:
        assert np.all(np.isfinite(signals.time)) and np.all(np.diff(signals.time) > 0)


def test_read_json_names_the_file(tmp_path):
    path = tmp_path / "metadata.json"
    path.write_text("[1, 2]")
    with pytest.raises(RunDirectoryError, match="metadata.json: expected a JSON object"):
        read_json(path)


_RUN = Path(__file__).resolve().parent / "data" / "fmu_accuracy_run"
_IDENTIFICATION = json.loads((_RUN / "identification.json").read_text())
_METADATA = json.loads((_RUN / "metadata.json").read_text())
_json_values = st.one_of(_numbers, st.none(), st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))


def _replaced(data: dict, path: tuple, value) -> dict:
    out = copy.deepcopy(data)
    node = out
    for key in path[:-1]:
        node = node.setdefault(key, {}) if isinstance(node, dict) else node[key]
    node[path[-1]] = value
    return out


_identification_keys = st.sampled_from(
    [("parameters", n, "value") for n in (*P1_NAMES, "B_w")] + [("parameters", n, "std") for n in P1_NAMES]
    + [("parameters", "m_ch"), ("parameters",), ("torque_lag", "value"), ("condition_number",),
       ("velocity_threshold",), ("covariance", "matrix"), ("rows_used",), ("ls_first_pass", "m_ch", "value")])


@SETTINGS
@given(key=_identification_keys, value=_json_values)
def test_identification_reader(tmp_path, key, value):
    """A value of any JSON type at any key the model is built from: refused naming the file and the key,
    or read with every parameter a finite float."""
    path = tmp_path / "identification.json"
    path.write_text(json.dumps(_replaced(_IDENTIFICATION, key, value)))
    try:
        result = load_identification(path)
    except RunDirectoryError as exc:
        assert "identification.json" in str(exc) and key[0] in str(exc)
    else:
        assert all(type(v) is float and math.isfinite(v) for v in (*result.values.values(), result.B_w))
        assert all(type(v) is float and math.isfinite(v) and v >= 0 for v in result.std.values())


@SETTINGS
@given(table=st.sampled_from(["geometry", "drive", "nominal"]), pick=st.integers(0, 20), value=_json_values)
def test_run_metadata_datasheet_reader(table, pick, value):
    """The data sheet a run's metadata.json stores is checked as a data-sheet file is, and refused as a
    run-directory error naming the file, the table and the key."""
    keys = list(_METADATA["datasheet"][table])
    key = keys[pick % len(keys)]
    meta = _replaced(_METADATA, ("datasheet", table, key), value)
    try:
        sheet = datasheet_from_metadata(meta, "run/metadata.json")
    except RunDirectoryError as exc:
        # the key itself, or the one it is checked against (max_torque >= rated_torque)
        assert "run/metadata.json" in str(exc) and f"[{table}] key '" in str(exc) and key in str(exc)
    else:
        assert all(math.isfinite(x) for x in (*sheet.nominal.p, sheet.drive.cycle_time, sheet.geometry.l))
        assert all(x > 0 for x in (sheet.geometry.l, sheet.geometry.r, sheet.drive.i_G, sheet.nominal.m_ch))


@SETTINGS
@given(pick=st.integers(0, 40), value=_json_values)
def test_campaign_settings_reader(pick, value):
    """Settings read back from a run (the twin's campaign drives them): a number of the right kind and
    range, or a ValueError naming the setting."""
    from dataclasses import fields as dataclass_fields

    from qomni.ident.campaign import CampaignSettings

    names = [f.name for f in dataclass_fields(CampaignSettings)]
    name = names[pick % len(names)]
    try:
        settings_ = CampaignSettings(**{name: value})
    except ValueError as exc:
        assert f"settings.{name}" in str(exc)
    else:
        got = getattr(settings_, name)
        assert type(got) in (int, float) and math.isfinite(got) and got >= 0


def test_unknown_run_format_refused():
    with pytest.raises(RunDirectoryError, match="format 'qomni-run/9'"):
        datasheet_from_metadata({**_METADATA, "format": "qomni-run/9"}, "metadata.json")


def test_unknown_motion_mode_refused():
    meta = _replaced(_METADATA, ("segments", 0, "k"), 7)
    with pytest.raises(RunDirectoryError, match=r"segments\[0\].*k = 7"):
        completed_steps(meta, "metadata.json")
