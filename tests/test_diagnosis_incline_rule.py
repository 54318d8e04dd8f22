"""The incline's rule (docs/diagnosis.md, Which): a slope is named by its component along the direction the
campaign's motion observes it, not by a component across the motion that reaches the data only through the
heading's wander."""
import math
from types import SimpleNamespace as NS

import numpy as np
import pytest

from qomni.diagnosis.hypotheses.base import RuleRows
from qomni.diagnosis.hypotheses.incline import RELEVANT, along_motion, confirm_along_motion

#: σ of (sin_x, sin_y) when the vehicle drives along world x with a heading wander of ~5 mrad: the across
#: component is determined 200 times worse than the along one.
SIGMA_ALONG, SIGMA_ACROSS = 2e-5, 4e-3


def _candidate(theta, heading=0.0, significant=True):
    """An incline candidate fitted on a campaign driving along ``heading`` (world frame, rad)."""
    c, s = math.cos(heading), math.sin(heading)
    rotation = np.array([[c, -s], [s, c]])
    cov = rotation @ np.diag([SIGMA_ALONG**2, SIGMA_ACROSS**2]) @ rotation.T
    base = np.zeros(3)
    return NS(hypothesis=NS(name="incline", variant=""), significant=significant, notes=[],
              fit=NS(theta=np.concatenate([base, theta]), theta_cov=np.block(
                  [[np.eye(3), np.zeros((3, 2))], [np.zeros((2, 3)), cov]])))


ROWS = RuleRows(None, None, None, 1, {})


@pytest.mark.parametrize("heading", [0.0, 0.7, -2.0])
@pytest.mark.parametrize("psi", [0.0, math.radians(60), math.radians(-115)])
def test_a_slope_that_does_work_along_the_motion_is_named(heading, psi):
    size = math.sin(0.005)                       # the suite's smallest slope, uphill psi off the motion
    theta = size * np.array([math.cos(heading + psi), math.sin(heading + psi)])
    c = _candidate(theta, heading)
    along, std, angle = along_motion(c.fit.theta[-2:], c.fit.theta_cov[-2:, -2:])
    assert abs(abs(along) - size * abs(math.cos(psi))) < 1e-12 and std == pytest.approx(SIGMA_ALONG)
    assert math.isclose(abs(math.cos(angle - heading)), 1.0, abs_tol=1e-9)
    confirm_along_motion([c], ROWS)
    assert c.significant and "along the best-observed direction" in c.notes[0]


@pytest.mark.parametrize("heading", [0.0, 1.2])
def test_a_slope_seen_only_across_the_motion_is_withdrawn(heading):
    across = math.sin(0.007) * np.array([-math.sin(heading), math.cos(heading)])
    wander = 1.5 * SIGMA_ALONG * np.array([math.cos(heading), math.sin(heading)])   # z = 1.5 along
    c = _candidate(across + wander, heading)
    confirm_along_motion([c], ROWS)
    assert not c.significant and "across the motion" in c.notes[0]


def test_a_significant_but_irrelevant_component_along_the_motion_is_withdrawn():
    theta = np.array([0.5 * RELEVANT, math.sin(0.007)])   # along x: z = 12, but half a flatness tolerance
    c = _candidate(theta)
    confirm_along_motion([c], ROWS)
    assert not c.significant


def test_other_hypotheses_and_unnamed_inclines_are_left_alone():
    other = NS(hypothesis=NS(name="payload", variant=""), significant=True, notes=[])
    unnamed = _candidate(np.array([0.0, 0.01]), significant=False)
    confirm_along_motion([other, unnamed], ROWS)
    assert other.significant and not unnamed.significant and not unnamed.notes


#: σ across the straight motion when the arcs yaw the chassis (about 1 mrad on a full campaign).
SIGMA_ACROSS_ARCS = 1.3e-3


def _with_arcs(theta, removed, significant=True):
    """An incline candidate of a campaign whose arcs determine the slope across the straight motion."""
    cov = np.diag([SIGMA_ALONG**2, SIGMA_ACROSS_ARCS**2])
    return NS(hypothesis=NS(name="incline", variant=""), significant=significant, notes=[],
              evaluation=NS(removed=removed),
              fit=NS(theta=np.concatenate([np.zeros(3), theta]), theta_cov=np.block(
                  [[np.eye(3), np.zeros((3, 2))], [np.zeros((2, 3)), cov]])))


def test_a_slope_across_the_straight_motion_that_the_arcs_determine_is_named_when_it_explains_most():
    """A floor sloping sideways to the straight step (uphill at 90°) does work in the arcs: its component
    across the motion is determined there and named, unless another candidate removes more held-out
    residual (an off-centre payload fits the same column in the arcs)."""
    lateral = np.array([1.0e-5, math.sin(0.015)])                       # z = 11.5 across, 0.5 along
    payload = NS(hypothesis=NS(name="payload", variant=""), significant=True, notes=[],
                 evaluation=NS(removed=40.0))
    c = _with_arcs(lateral, removed=250.0)
    confirm_along_motion([payload, c], ROWS)
    assert c.significant and "across the best-observed direction" in c.notes[0]
    c = _with_arcs(lateral, removed=25.0)
    confirm_along_motion([payload, c], ROWS)
    assert not c.significant and "another candidate removes more" in c.notes[0]
    small = _with_arcs(np.array([0.0, 0.5 * RELEVANT]), removed=250.0)   # z = 0.4: a floor's flatness
    confirm_along_motion([payload, small], ROWS)
    assert not small.significant and "heading's wander" in small.notes[0]
    unsure = _with_arcs(np.array([0.0, 2.0 * SIGMA_ACROSS_ARCS]), removed=250.0)    # z = 2, p = 0.05
    confirm_along_motion([unsure], ROWS)
    assert not unsure.significant
