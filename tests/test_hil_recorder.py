"""The bus recorder: frames handed to a writer process in batches come back from the files unchanged."""
import can
import pytest

from qomni.hil.tools import recorder as R


def _frames(n: int) -> list[can.Message]:
    kinds = [
        dict(arbitration_id=0x181, data=bytes(range(8)), is_rx=True),
        dict(arbitration_id=0x80, data=b"", is_rx=False),
        dict(arbitration_id=0x1ABCDE, data=b"\x01\x02", is_extended_id=True, is_rx=True),
        dict(arbitration_id=0x601, dlc=8, is_remote_frame=True, is_rx=False),
        dict(arbitration_id=0x123, data=bytes(range(12)), is_fd=True, bitrate_switch=True, is_rx=True),
    ]
    out = []
    for i in range(n):
        kind = {"is_extended_id": False, **kinds[i % len(kinds)]}
        out.append(can.Message(timestamp=1.7e9 + 0.001 * i, **kind))
    return out


def _fields(msg: can.Message) -> tuple:
    return (msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, msg.is_rx, msg.is_fd,
            msg.bitrate_switch, msg.dlc if not msg.is_remote_frame else None, bytes(msg.data or b""))


@pytest.mark.parametrize("suffix", [".blf", ".log"])
def test_every_frame_comes_back_in_order_with_its_fields(tmp_path, suffix):
    """More frames than a batch holds, of every kind the master meets (standard, extended, remote, empty,
    CAN FD): each file holds all of them, in order, with their identifier, flags, DLC, data and time."""
    sent = _frames(3 * R.BATCH_FRAMES + 7)
    path = tmp_path / f"bus{suffix}"
    recorder = R.BusRecorder(path)
    for msg in sent:
        recorder.on_message_received(msg)
    recorder.stop()
    assert recorder.frames == len(sent) and recorder.errors == 0
    back = list(can.LogReader(path))
    assert [_fields(m) for m in back] == [_fields(m) for m in sent]
    start = back[0].timestamp - sent[0].timestamp           # a BLF file may count from its first frame
    assert [m.timestamp - start for m in back] == pytest.approx([m.timestamp for m in sent], abs=2e-6)


def test_both_files_of_one_recorder_hold_the_same_frames(tmp_path):
    sent = _frames(40)
    recorder = R.BusRecorder([tmp_path / "bus.blf", tmp_path / "bus.log"], channel=3)
    for msg in sent:
        recorder.on_transmit(msg)                              # the master's own frames: stamped, Tx
    recorder.stop()
    blf, log = (list(can.LogReader(tmp_path / name)) for name in ("bus.blf", "bus.log"))
    assert [_fields(m) for m in blf] == [_fields(m) for m in log]
    assert len(blf) == 40 and not any(m.is_rx for m in blf)


def test_a_file_that_cannot_be_written_fails_the_constructor(tmp_path):
    with pytest.raises(ValueError, match="unknown"):
        R.BusRecorder(tmp_path / "bus.unknownsuffix")
    with pytest.raises(FileNotFoundError):
        R.BusRecorder(tmp_path / "missing" / "bus.blf")


def test_a_writer_process_that_dies_costs_frames_not_the_master(tmp_path):
    """Frames the recorder can no longer hand over are counted in ``errors``; recording never raises
    into the master's thread, and stop returns."""
    recorder = R.BusRecorder(tmp_path / "bus.blf")
    recorder._process.kill()
    recorder._process.wait()
    for msg in _frames(2 * R.BATCH_FRAMES):
        recorder.on_message_received(msg)
    recorder.stop()
    assert recorder.errors >= R.BATCH_FRAMES
    recorder.on_message_received(_frames(1)[0])                  # after stop: ignored
    assert recorder.frames == 2 * R.BATCH_FRAMES


def test_frames_given_as_values_are_recorded_as_their_messages(tmp_path):
    """The in-process bus hands data frames over as (can_id, data, timestamp) (qomni.hil.virtual_bus):
    ``on_frame`` and ``on_transmit_frame`` record exactly what ``on_message_received`` and ``on_transmit`` of
    the same frame's message record."""
    by_values, by_messages = R.BusRecorder(tmp_path / "a.log"), R.BusRecorder(tmp_path / "b.log")
    for i in range(20):
        data = bytes(range(i % 9))
        msg = can.Message(timestamp=1.7e9 + i, arbitration_id=0x181 + i, data=data, is_extended_id=False,
                          is_rx=True)
        by_values.on_frame(0x181 + i, data, 1.7e9 + i)
        by_messages.on_message_received(msg)
        by_values.on_transmit_frame(0x201, data)
        by_messages.on_transmit(can.Message(arbitration_id=0x201, data=data, is_extended_id=False))
    by_values.stop()
    by_messages.stop()
    a, b = (list(can.LogReader(tmp_path / name)) for name in ("a.log", "b.log"))
    assert len(a) == 40 and [_fields(m) for m in a] == [_fields(m) for m in b]
    assert [m.timestamp for m in a[::2]] == [m.timestamp for m in b[::2]]      # received: their own stamp
