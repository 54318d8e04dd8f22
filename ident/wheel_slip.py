"""Wheels that do not roll: a recording in which a wheel spun, lifted or skidded.

The paper's model rests on rolling without slip, the constraints (1): every wheel's rolling rate is
what the chassis' motion and the steering make of its contact point. A wheel that leaves the ground
(an off-centre load that tips the vehicle), spins on a slippery floor or skids when braked breaks (1),
and a campaign with such a wheel still runs to its end and gives parameters: wrong ones (a 2000 kg
load 0.7 m off-centre on the prototype lifted drive rl, which turned at 600 rad/s instead of 38 on
the motor side, and identified m_ch = 263 kg). The drives' own signals agree with each other there
(:mod:`.plausibility`), so only the wheels compared with one another show it.

The four rolling constraints and four lateral ones hold three chassis velocities, so each wheel's
rolling rate is predicted by the other seven constraints (least squares, as odometry (3) solves all
eight) and compared with its own: the excess, r (β̇_i − β̇_i,pred) in m/s at the contact point.
Summed over 1 s windows (:data:`WINDOW`) it is how far the wheel rolled beyond the way its contact
point travelled. A wheel slips where that exceeds :data:`MAX_SLIP_RATIO` of the way plus
:data:`SLIP_FLOOR`, in every window that starts over at least :data:`MIN_SLIP_SPAN` in a row.
"""
from __future__ import annotations

import numpy as np

from qomni.datasheet import DataSheet

from . import kinematics
from .plausibility import MAX_SPACING_JITTER
from .recording import WHEELS, RecordingError, Signals

#: Window over which a wheel's excess rolling is summed (s): long against a backlash's crossing or a
#: glitch, short against a spin that lasts a second.
WINDOW = 1.0
#: Longitudinal slip ratio beyond which a tyre no longer rolls: a tyre's driving force peaks at a slip
#: of 0.1–0.2 (rubber on a hard floor) and falls beyond it, where the wheel spins or skids. A worn tyre
#: 5 % under the data sheet's radius (the realistic end of ``wheel_radius``) reads 0.05.
MAX_SLIP_RATIO = 0.2
#: Excess (m) a rolling wheel may show in a window even at rest: ten times the way a 20 mrad backlash
#: (the realistic end of ``backlash``) lets the motor turn ahead of a 0.1 m wheel, 2 mm.
SLIP_FLOOR = 0.02
#: Span of window starts in a row that must all exceed the bound (s): a single glitch in a position
#: moves only the sums of the windows that start or end at it; a spinning wheel moves every window that
#: holds the spin.
MIN_SLIP_SPAN = 0.1


def rolling_excess(signals: Signals, sheet: DataSheet) -> tuple[np.ndarray, np.ndarray]:
    """Each wheel's rolling rate against what the other constraints of (1) predict for it.

    Args:
        signals: N ≥ 3 rows, increasing time. sheet: geometry (l, b, a, r) and gear ratio i_G.
    Returns:
        (excess, predicted): (N, 4) each, m/s at the contact point, wheels fl, rl, fr, rr;
        ``excess`` = r (β̇_i − β̇_i,pred), ``predicted`` = r β̇_i,pred, with β = motor position / i_G
        (wheel side) and rates by ``numpy.gradient``.
    """
    g = sheet.geometry
    alpha = np.asarray(signals.alpha, dtype=float)
    beta = np.asarray(signals.motor_position, dtype=float) / sheet.drive.i_G
    alpha_d = np.gradient(alpha, signals.time, axis=0)
    beta_d = np.gradient(beta, signals.time, axis=0)
    A = kinematics.constraint_matrix(alpha, g)
    known = np.einsum("nij,nj->ni", A[:, :, 3:5], alpha_d)
    excess = np.empty_like(beta_d)
    predicted = np.empty_like(beta_d)
    for i in range(4):
        rows = [r for r in range(8) if r != 4 + i]
        others = [j for j in range(4) if j != i]
        a = A[:, rows]
        rhs = -(known[:, rows] + np.einsum("nij,nj->ni", a[:, :, 5:][:, :, others], beta_d[:, others]))
        a_ch = a[:, :, :3]
        qd_ch = np.linalg.solve(np.einsum("nki,nkj->nij", a_ch, a_ch),
                                np.einsum("nki,nk->ni", a_ch, rhs)[..., None])[..., 0]
        row = A[:, 4 + i]
        rate = -(np.einsum("nj,nj->n", row[:, :3], qd_ch) + known[:, 4 + i]) / row[:, 5 + i]
        predicted[:, i] = g.r * rate
        excess[:, i] = g.r * (beta_d[:, i] - rate)
    return excess, predicted


def _runs_at_least(mask: np.ndarray, length: int) -> np.ndarray:
    """Start indices of the runs of True in ``mask`` (1-D) that hold at least ``length`` entries."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return starts[ends - starts >= length]


def check_rolling(signals: Signals, sheet: DataSheet, path: str) -> None:
    """Every wheel rolls as the others and the steering say it must (constraints (1) of the paper).

    Over each :data:`WINDOW` of consecutive rows the excess of :func:`rolling_excess` is summed into the
    way the wheel rolled beyond its contact point, and compared with :data:`MAX_SLIP_RATIO` times the way
    the contact point travelled plus :data:`SLIP_FLOOR`. Rows more than half a cycle off the recording's
    spacing (steps cut out of a run) part the recording into stretches that are judged apart; a stretch
    shorter than one window is not judged.

    Raises:
        RecordingError: a wheel exceeded the bound in every window starting over
            :data:`MIN_SLIP_SPAN` in a row; names the file, the line and time of the first such
            window, its step, the wheel whose excess is largest against its bound there, and both ways.
    """
    time = np.asarray(signals.time, dtype=float)
    if len(time) < 3:
        return
    ts = float(np.median(np.diff(time)))
    width = int(round(WINDOW / ts))
    cuts = np.flatnonzero(np.abs(np.diff(time) - ts) > MAX_SPACING_JITTER * ts) + 1
    for first, stop in zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [len(time)]])):
        if stop - first > max(width, 2):
            _check_stretch(signals.select(np.arange(len(time))[first:stop]), sheet, width, ts, int(first), path)


def _check_stretch(signals: Signals, sheet: DataSheet, width: int, ts: float, first: int, path: str) -> None:
    """:func:`check_rolling` on consecutive rows, the first of them row ``first`` of the file."""
    time = np.asarray(signals.time, dtype=float)
    excess, predicted = rolling_excess(signals, sheet)
    dt = np.gradient(time)[:, None]
    beyond = np.vstack([np.zeros((1, 4)), np.cumsum(excess * dt, axis=0)])
    way = np.vstack([np.zeros((1, 4)), np.cumsum(np.abs(predicted) * dt, axis=0)])
    beyond, way = beyond[width:] - beyond[:-width], way[width:] - way[:-width]
    slipping = np.abs(beyond) > MAX_SLIP_RATIO * way + SLIP_FLOOR
    span = max(1, int(round(MIN_SLIP_SPAN / ts)))
    firsts = [int(starts[0]) for i in range(4) if len(starts := _runs_at_least(slipping[:, i], span))]
    if not firsts:
        return
    j = min(firsts)
    # One wheel off the ground also moves the others' predictions, which it enters: name the wheel
    # whose excess is largest against its bound where the first slip starts.
    i = int(np.argmax(np.abs(beyond[j]) / (MAX_SLIP_RATIO * way[j] + SLIP_FLOOR)))
    raise RecordingError(
        f"{path}:{first + j + 2}: wheel {WHEELS[i]} rolled {float(beyond[j, i]):+.3f} m beyond the "
        f"{float(way[j, i]):.3f} m its contact point travelled in the {WINDOW:g} s from t = {time[j]:.3f} s "
        f"(step '{signals.step[j]}'), more than a rolling tyre's slip ({MAX_SLIP_RATIO:g} of the way + "
        f"{SLIP_FLOOR:g} m): the wheel spun, lifted or skidded, or the data sheet's geometry (l, b, a, r) is "
        "not this vehicle's; the model's rolling constraints (1) do not hold for this recording")


__all__ = ["check_rolling", "rolling_excess", "WINDOW", "MAX_SLIP_RATIO", "SLIP_FLOOR", "MIN_SLIP_SPAN"]
