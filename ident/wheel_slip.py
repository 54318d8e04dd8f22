"""Wheels that do not roll: a recording in which a wheel spun or lifted.

The paper's model rests on rolling without slip, the constraints (1): every wheel's rolling rate is
what the chassis' motion and the steering make of its contact point. A wheel that leaves the ground
(an off-centre load that tips the vehicle) or spins on a slippery floor breaks (1),
and a campaign with such a wheel still runs to its end and gives parameters: wrong ones (a 2000 kg
load 0.7 m off-centre on the prototype lifted drive rl, which turned at 600 rad/s instead of 38 on
the motor side, and identified m_ch = 263 kg). The drives' own signals agree with each other there
(:mod:`.plausibility`), so only the wheels compared with one another show it.

The four rolling constraints and four lateral ones hold three chassis velocities, so each wheel's
rolling rate is predicted by the other seven constraints (least squares, as odometry (3) solves all
eight) and compared with its own: the excess r (β̇_i − β̇_i,pred), m/s at the contact point. Summed over
1 s windows (:data:`WINDOW`) it is how far the wheel rolled beyond the way its contact point travelled
(∫|r β̇_i,pred|). A wheel spins where that is more than the slip ratio :data:`MAX_SLIP_RATIO` allows,
way × s/(1 − s), plus :data:`SLIP_FLOOR`, in every window that starts over at least
:data:`MIN_SLIP_SPAN` in a row. The bound is wide: steering friction at the end of its realistic range
holds the steering off the ICR in the arcs and the wheels scrub (Stribeck friction in both joints,
breakaway ratio 2.5: 0.19 m beyond a way of 0.32 m); that vehicle is one the diagnosis must read. A
wheel that skids (rolls less than its contact point travels, at most the whole way) stays within it.
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
#: Slip ratio s = (rolled − contact way)/rolled beyond which a wheel is off the ground or spinning: a
#: tyre's driving force peaks at a slip of 0.1–0.2 and falls beyond it, and a wheel that turns four
#: times as far as its contact point travels drives nothing. Wheels on the ground stay within a quarter
#: of the bound at the ends of the effects' realistic ranges; a lifted wheel read 3.4 times it.
MAX_SLIP_RATIO = 0.75
#: Way (m) a wheel may roll beyond its contact point in a window at any speed: a third of a 0.1 m
#: wheel's turn, a hundred times what a 20 mrad backlash (the realistic end of ``backlash``) lets the
#: motor turn ahead of the wheel.
SLIP_FLOOR = 0.2
#: Span of window starts in a row that must all exceed the bound (s): a single glitch in a position
#: moves only the sums of the windows that start or end at it; a spinning wheel moves every window that
#: holds the spin.
MIN_SLIP_SPAN = 0.1
#: Motion modes (9) whose rows are judged: the chassis drives on its wheels.
DRIVING_MODES = (2, 3, 4)


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
    """Every wheel rolls as the others and the steering say it must (constraints (1) of the paper), in
    the steps where the chassis drives (motion modes 2, 3 and 4).

    Over each :data:`WINDOW` of consecutive rows the excess of :func:`rolling_excess` is summed into the way
    the wheel rolled beyond its contact point, and compared with the way the contact point travelled times
    s/(1 − s), s = :data:`MAX_SLIP_RATIO`, plus :data:`SLIP_FLOOR`. Steps in mode 1 (the chassis at rest, the
    steering turning) are left out: there a contact point travels on a circle of radius a about its steering
    axis, a few centimetres, and its tyre pivots and scrubs rather than rolls (a vehicle with Stribeck
    friction in both joints at the realistic range's end skids its wheels 0.03 m a second there, and a lifted
    wheel spins in every driving step as well). Rows more than half a cycle off the recording's spacing (steps
    cut out of a run) part the rest into stretches that are judged apart; a stretch shorter than one window is
    not judged.

    Raises:
        RecordingError: a wheel exceeded the bound in every window starting over
            :data:`MIN_SLIP_SPAN` in a row; names the file, the line and time of the first such
            window, its step, the wheel that rolled farthest beyond its bound there, and both ways.
    """
    time = np.asarray(signals.time, dtype=float)
    if len(time) < 3:
        return
    ts = float(np.median(np.diff(time)))
    width = int(round(WINDOW / ts))
    driving = np.isin(np.asarray(signals.k), DRIVING_MODES)
    apart = np.abs(np.diff(time) - ts) > MAX_SPACING_JITTER * ts
    edges = np.flatnonzero(np.diff(driving.astype(np.int8)) | apart) + 1
    for first, stop in zip(np.concatenate([[0], edges]), np.concatenate([edges, [len(time)]])):
        if driving[first] and stop - first > max(width, 2):
            _check_stretch(signals.select(np.arange(len(time))[first:stop]), sheet, width, ts, int(first), path)


def _check_stretch(signals: Signals, sheet: DataSheet, width: int, ts: float, first: int, path: str) -> None:
    """:func:`check_rolling` on consecutive rows, the first of them row ``first`` of the file."""
    time = np.asarray(signals.time, dtype=float)
    excess, predicted = rolling_excess(signals, sheet)
    dt = np.gradient(time)[:, None]
    beyond = np.vstack([np.zeros((1, 4)), np.cumsum(excess * dt, axis=0)])
    way = np.vstack([np.zeros((1, 4)), np.cumsum(np.abs(predicted) * dt, axis=0)])
    beyond, way = beyond[width:] - beyond[:-width], way[width:] - way[:-width]
    bound = way * MAX_SLIP_RATIO / (1 - MAX_SLIP_RATIO) + SLIP_FLOOR
    spinning = np.abs(beyond) > bound
    span = max(1, int(round(MIN_SLIP_SPAN / ts)))
    firsts = [int(starts[0]) for i in range(4) if len(starts := _runs_at_least(spinning[:, i], span))]
    if not firsts:
        return
    j = min(firsts)
    # One wheel off the ground also moves the others' predictions, which it enters: name the wheel
    # that rolled farthest beyond its bound where the first spin starts.
    i = int(np.argmax(np.abs(beyond[j]) / bound[j]))
    raise RecordingError(
        f"{path}:{first + j + 2}: wheel {WHEELS[i]} rolled {abs(float(beyond[j, i])):.3f} m beyond the "
        f"{float(way[j, i]):.3f} m its contact point travelled in the {WINDOW:g} s from t = {time[j]:.3f} s "
        f"(step '{signals.step[j]}'), a slip ratio above {MAX_SLIP_RATIO:g} (bound {float(bound[j, i]):.3f} m "
        "with its floor): the wheel spun or lifted, or the data sheet's geometry (l, b, a, r) is not this "
        "vehicle's; the model's rolling constraints (1) do not hold for this recording")


__all__ = ["check_rolling", "rolling_excess", "WINDOW", "MAX_SLIP_RATIO", "SLIP_FLOOR", "MIN_SLIP_SPAN",
           "DRIVING_MODES"]
