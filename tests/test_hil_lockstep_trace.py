"""Lock-step determinism: a seeded short run puts exactly the reference's frames on the bus and leaves the
plant in exactly the reference's states, bit for bit (tests/lockstep_trace.py).

Frame order: from the master's first SDO request on, every frame is caused by the one before it
(request → response, RPDOs + SYNC → TPDOs), so the whole stream must match in order. Before that, the
master resets the six nodes and each answers with its boot-up message; how the master's NMT commands
interleave with the boot-ups is up to thread scheduling, so there each sender's own frames must match
in order.
"""
from __future__ import annotations

import numpy as np
import pytest

from lockstep_trace import REFERENCE, record

_MASTER_FUNCTIONS = {0x0, 0x4, 0x6, 0x8, 0xA, 0xC}      # COB-ID >> 7: NMT, RPDO1…4, SDO request


def _sent_by_master(ids: np.ndarray) -> np.ndarray:
    return np.isin(ids >> 7, list(_MASTER_FUNCTIONS)) | (ids == 0x80)


def _first_mismatch(a: np.ndarray, b: np.ndarray) -> int | None:
    n = min(len(a), len(b))
    diff = np.flatnonzero(np.any((a[:n] != b[:n]).reshape(n, -1), axis=1))
    return int(diff[0]) if len(diff) else (None if len(a) == len(b) else n)


@pytest.mark.parametrize("plant_process", [False, True], ids=["plant in the bus' process", "plant process"])
def test_lockstep_run_is_bit_identical_to_the_reference_trace(plant_process):
    reference = np.load(REFERENCE)
    trace = record(plant_process=plant_process)
    frames = {key: np.column_stack([trace["arbitration_id"], trace["dlc"], trace["data"]]).astype(np.int64)
              for key, trace in (("run", trace), ("reference", reference))}
    run, ref = frames["run"], frames["reference"]
    start = [int(np.flatnonzero((f[:, 0] >> 7) == 0xC)[0]) for f in (run, ref)]
    assert start[0] == start[1], f"boot phase has {start[0]} frames, reference {start[1]}"
    for who, pick in (("master", True), ("devices", False)):
        mine = run[:start[0]][_sent_by_master(run[:start[0], 0]) == pick]
        theirs = ref[:start[1]][_sent_by_master(ref[:start[1], 0]) == pick]
        at = _first_mismatch(mine, theirs)
        assert at is None, f"boot phase, frames of the {who} differ from their frame {at} on"
    at = _first_mismatch(run[start[0]:], ref[start[1]:])
    if at is not None:
        got, want = run[start[0]:][at:at + 1].tolist(), ref[start[1]:][at:at + 1].tolist()
        raise AssertionError(f"frame {start[0] + at} differs: got {got}, reference {want} (id, DLC, data)")
    # bit-identical floats: compare the raw bytes, so that no tolerance and no NaN rule hides a change
    for key in ("plant_state", "measurement"):
        assert trace[key].shape == reference[key].shape, key
        assert trace[key].tobytes() == reference[key].tobytes(), f"{key} differs"
    assert len(ref) > 2000 and reference["plant_state"].shape[0] == 120    # the run did cycle
