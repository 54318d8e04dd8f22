"""Lock-step determinism: a seeded short run puts exactly the reference's frames on the bus, in the same
order, and leaves the plant in exactly the reference's states (bit for bit; tests/lockstep_trace.py)."""
from __future__ import annotations

import numpy as np

from lockstep_trace import REFERENCE, record


def test_lockstep_run_is_bit_identical_to_the_reference_trace():
    reference = np.load(REFERENCE)
    trace = record()
    ids, ref_ids = trace["arbitration_id"], reference["arbitration_id"]
    if len(ids) != len(ref_ids) or not np.array_equal(ids, ref_ids):
        n = min(len(ids), len(ref_ids))
        first = next((i for i in range(n) if ids[i] != ref_ids[i]), n)
        raise AssertionError(f"frame order differs from frame {first} on ({len(ids)} frames, reference "
                             f"{len(ref_ids)}): got 0x{int(ids[first]) if first < len(ids) else -1:X}, reference "
                             f"0x{int(ref_ids[first]) if first < len(ref_ids) else -1:X}")
    assert np.array_equal(trace["dlc"], reference["dlc"])
    assert np.array_equal(trace["data"], reference["data"])
    # bit-identical floats: compare the raw bytes, so that no tolerance and no NaN rule hides a change
    for key in ("plant_state", "measurement"):
        assert trace[key].shape == reference[key].shape, key
        assert trace[key].tobytes() == reference[key].tobytes(), f"{key} differs"
    assert len(ref_ids) > 1000 and reference["plant_state"].shape[0] >= 120    # the run did cycle
