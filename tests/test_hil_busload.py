"""Worst-case bus load of the active PDO mapping (qomni.hil.tools.busload)."""
import pytest

from qomni.hil.tools.busload import bus_load, frame_bits
from qomni.hil.master.decode import node_files
from qomni.hil.layout import DRIVE_EDS


def test_frame_bits_worst_case_stuffing():
    assert [frame_bits(n) for n in (0, 4, 6, 8)] == [55, 95, 115, 135]
    with pytest.raises(ValueError):
        frame_bits(9)


def test_shipped_mapping_at_1_mbit(tmp_path):
    load = bus_load(1_000_000, 0.002)
    # SYNC with its counter (1 B) + 4 RPDO (4 B) + 8 drive TPDO (6 B) + 2 encoder TPDO (4 B) + 6 heartbeats at 1 s
    assert load.frames[0] == ("SYNC", 1, 1.0, 65.0)
    assert load.bits_per_cycle == pytest.approx(65 + 4 * 95 + 8 * 115 + 2 * 95 + 6 * 0.002 * 65)
    assert load.load == pytest.approx(0.778, abs=0.001)
    lean = tmp_path / "drive402.eds"                       # TPDO2 every 2nd SYNC halves its share
    lean.write_bytes(DRIVE_EDS.read_bytes().replace(
        b"[1801sub2]\r\nParameterName=Transmission type\r\nObjectType=0x7\r\nDataType=0x0005\r\nAccessType=rw\r\n"
        b"DefaultValue=1", b"[1801sub2]\r\nParameterName=Transmission type\r\nObjectType=0x7\r\n"
        b"DataType=0x0005\r\nAccessType=rw\r\nDefaultValue=2"))
    assert bus_load(1_000_000, 0.002, node_files(eds_dir=tmp_path)).bits_per_cycle == \
        pytest.approx(load.bits_per_cycle - 4 * 115 / 2)
    plain = tmp_path / "plain"
    plain.mkdir()
    (plain / "drive402.eds").write_bytes(DRIVE_EDS.read_bytes().replace(
        b"[1019]\r\nParameterName=Synchronous counter overflow value\r\nObjectType=0x7\r\nDataType=0x0005\r\n"
        b"AccessType=rw\r\nDefaultValue=240", b"[1019]\r\nParameterName=Synchronous counter overflow value\r\n"
        b"ObjectType=0x7\r\nDataType=0x0005\r\nAccessType=rw\r\nDefaultValue=0"))
    assert bus_load(1_000_000, 0.002, node_files(eds_dir=plain)).frames[0] == ("SYNC", 0, 1.0, 55.0)
    with pytest.raises(ValueError):
        bus_load(0, 0.002)
