"""What the lifted vehicle's single-axis run tells the diagnosis (docs/diagnosis.md, Which): the drive a
torque-constant error is on, where the wheels' own data cannot rank a weaker and a stronger drive."""
from types import SimpleNamespace as NS

import pytest

from qomni.diagnosis.hypotheses.base import RuleRows
from qomni.diagnosis.hypotheses.torque_constant_error import (LIFTED_Z, lifted_inertia_ratio,
                                                              resolve_drive)
from qomni.conventions import WHEELS

B_W, SIGMA = 0.120, 0.0008


def _lifted(faulty: dict[str, float] | None = None) -> dict:
    """Lifted wheels whose B_w reads B_W/f on a drive of torque-constant factor f (one σ of noise apart)."""
    faulty = faulty or {}
    wobble = dict(zip(WHEELS, (-0.5, 0.3, 0.0, 0.6)))
    return {w: {"B_w": (B_W / faulty.get(w, 1.0) + wobble[w] * SIGMA, SIGMA),
                "d_vw": (0.73, 0.002), "d_cw": (3.95, 0.014)} for w in WHEELS}


def _candidate(wheel: str, factor_minus_one: float, significant: bool = True):
    return NS(hypothesis=NS(name="torque_constant_error", variant=f"drive {wheel}"),
              magnitude=NS(value=factor_minus_one), significant=significant, notes=[])


def _rows(lifted):
    return RuleRows(None, None, None, 1, {}, lifted)


def test_a_faulty_drive_reads_its_wheels_inertia_as_one_over_its_factor_against_the_others_median():
    lifted = _lifted({"rl": 1.13})
    ratio, std = lifted_inertia_ratio(lifted, "rl")
    assert ratio == pytest.approx(1 / 1.13, rel=0.01)
    assert abs(ratio - 1) / std > LIFTED_Z
    for w in ("fl", "fr", "rr"):      # the median keeps the faulty wheel out of the others' reference
        r, s = lifted_inertia_ratio(lifted, w)
        assert abs(r - 1) / s < 1.5


def test_the_lifted_run_names_the_stronger_drive_where_the_wheels_data_name_a_weaker_one_beside_it():
    named, equivalent = _candidate("fl", -0.108), _candidate("rl", 0.109)
    others = [_candidate("fr", 0.01, False), _candidate("rr", -0.01, False)]
    resolve_drive([named, equivalent, *others], _rows(_lifted({"rl": 1.13})))
    assert equivalent.significant and not named.significant
    assert "wheel rl" in equivalent.notes[0] and "drive rl" in named.notes[0]


@pytest.mark.parametrize("lifted,why", [
    (None, "no single-axis run"),
    (_lifted(), "no wheel off"),
    (_lifted({"rl": 1.13, "fr": 0.9}), "two wheels off: the lifted run singles out none"),
    (_lifted({"rl": 0.88}), "the wheel says weaker, the candidate stronger"),
])
def test_the_lifted_run_changes_nothing_where_it_does_not_single_out_the_candidates_drive(lifted, why):
    named, equivalent = _candidate("fl", -0.108), _candidate("rl", 0.109)
    resolve_drive([named, equivalent], _rows(lifted))
    assert named.significant and equivalent.significant, why
