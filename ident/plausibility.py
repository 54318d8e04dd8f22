"""Whole-recording checks of a campaign run: every row the metadata promises is there, one cycle after
the other; every drive's signals are alive and agree with each other; no torque or steering angle lies
beyond the vehicle's limits.

Each value of ``signals.csv`` is checked as it is read (:func:`.recording.read_signals`: finite, time
increasing); single glitches are repaired (:mod:`.spikes`). What neither sees is a file cut short after
a step that ``metadata.json`` says completed or with rows missing inside a step, a drive whose signal is
dead or wired the wrong way for the whole run, or a column in another unit: each still gives parameters,
wrong ones (a zeroed torque actual on one drive: m_ch −26 %; a frozen encoder: m_ch +35 %; 30 rows
missing in the straight step: m_ch −11 %). These checks refuse such a run with a
:class:`~.recording.RecordingError` naming the file, the line, step or column and what is wrong.
"""
from __future__ import annotations

import numpy as np
from scipy.stats import spearmanr

from . import kinematics
from .recording import WHEELS, RecordingError, Signals

#: Shortest recording the drive checks judge (s): a few seconds of a campaign step move every drive.
MIN_SPAN = 2.0
#: Rows a completed step may lack against its duration / T_s: the time stamps' rounding at its ends …
ROW_TOLERANCE = 2
#: … or this share of them, where time stamps jitter (a bus logger's): a file cut short loses far more.
ROW_SHARE_TOLERANCE = 0.005
#: Largest departure of a row-to-row time step from the recording's median spacing, as its share: a
#: logger's time stamps jitter by a few per cent of T_s; a missing row doubles the step.
MAX_SPACING_JITTER = 0.5
#: Share by which a torque actual may read above the drive's peak torque: its measurement noise
#: (the emulator's: 0.01 N m against 6 N m).
TORQUE_OVER_MAX = 0.1
#: Angle (rad) a steering sensor may read beyond the stops: its noise, a few LSB of a 14-bit sensor.
ANGLE_OVER_LIMIT = 0.05
#: Least R² of a drive's position change over a cycle against T_s times its velocity actual. The
#: velocity actual (0x606C) is the position's (0x6064) rate; a drive's own filtering and time stamping
#: leave R² near 1 (the emulator's drives: 1.000), a frozen encoder 0, a reversed polarity −3.
MIN_POSITION_VELOCITY_R2 = 0.5
#: Least correlation of a drive's torque actual (0x6077) with the torque the master commanded: the
#: current loop follows its demand (1.000 on the emulator's drives with delays, lags and limits), a
#: torque actual of the wrong sign or another drive's does not.
MIN_TORQUE_CORRELATION = 0.5
#: Largest median distance (rad) of a mode-3 or mode-4 step's steering angles from the mode's fixed
#: configuration (9) over :data:`MODE_WINDOW`: there the distance is each wheel's heading error, a slip
#: angle, and 0.3 rad lies well past the saturation of a tyre's side force (0.1–0.2 rad). Beyond it the
#: wheels slide sideways rather than hold mode k, and the rows are another step's (a decode laid over
#: another campaign's metadata: 1.13 rad). The campaign holds the rotation within 0.1 rad at the
#: realistic range's ends (both-joint Stribeck friction of breakaway ratio 2.5: 0.099 rad; window medians).
MAX_CONFIGURATION_ERROR = 0.3
#: Window of a step's rows whose median :data:`MAX_CONFIGURATION_ERROR` bounds (s).
MODE_WINDOW = 1.0


def check_coverage(signals: Signals, segments: list[dict], cycle_time: float, path: str) -> None:
    """Every completed step (``segments``: ``{name, t_start, t_end}``) has its rows in ``signals``.

    A step of duration D holds D/T rows in (t_start, t_end], T the recording's mean period (within 1 % of
    ``cycle_time``): the recorder writes one per SYNC, a missed TPDO as the value held from the cycle
    before. Tolerance: :data:`ROW_TOLERANCE` rows or :data:`ROW_SHARE_TOLERANCE` of them.

    Raises:
        RecordingError: the rows are not ``cycle_time`` apart (median spacing, 1 %), two consecutive rows
            are not one spacing apart (:func:`_check_spacing`: a row missing), a step has fewer or
            more rows than that, rows of another step inside it (names the step, its time span and
            the rows found), or a row whose motion mode k is not its step's (names the line).
    """
    time = np.asarray(signals.time, dtype=float)
    period = cycle_time
    if len(time) > 1:
        dt = np.diff(time)
        spacing = float(np.median(dt))
        if abs(spacing - cycle_time) > 0.01 * cycle_time:
            raise RecordingError(f"{path}: rows are {spacing:.6g} s apart, the data sheet's cycle time is "
                                 f"{cycle_time:.6g} s: the recording and its metadata do not belong together")
        step = np.asarray(signals.step)
        _check_spacing(time, dt, step[1:] == step[:-1], spacing, path)
        # the recording's own period: a master's clock a little off the nominal T_s (or a logger's time
        # stamps) changes how many rows a long step holds, not whether it is complete
        period = float(np.mean(dt[dt < 1.5 * spacing]))
    eps = 1e-6 * cycle_time
    for seg in segments:
        t0, t1 = seg["t_start"], seg["t_end"]
        inside = (time > t0 + eps) & (time <= t1 + eps)
        expected = int(round((t1 - t0) / period))
        found = int(inside.sum())
        tolerance = max(ROW_TOLERANCE, int(ROW_SHARE_TOLERANCE * expected))
        if found > expected + tolerance:
            raise RecordingError(f"{path}: step '{seg['name']}' ({t0:.3f}–{t1:.3f} s) has {found} rows, more "
                                 f"than its {expected} cycles: rows are duplicated or the times are wrong")
        if found < expected - tolerance:
            end = f"; the file ends at {time[-1]:.3f} s" if time[-1] < t1 - cycle_time else ""
            raise RecordingError(f"{path}: step '{seg['name']}' ({t0:.3f}–{t1:.3f} s) completed by the "
                                 f"metadata has {found} of its {expected} rows{end}: the recording is cut "
                                 "short or rows are missing")
        others = sorted(set(signals.step[inside]) - {seg["name"]})
        if others:
            raise RecordingError(f"{path}: rows of {', '.join(others)} inside step '{seg['name']}' "
                                 f"({t0:.3f}–{t1:.3f} s): the recording does not match its metadata")
        modes = np.asarray(signals.k)[inside]
        if len(modes) and (modes != seg["k"]).any():
            i = int(np.flatnonzero(inside)[np.flatnonzero(modes != seg["k"])[0]])
            raise RecordingError(f"{path}:{i + 2}: motion mode k = {int(signals.k[i])} inside step "
                                 f"'{seg['name']}', which the metadata records in mode k = {seg['k']}: the "
                                 "recording does not match its metadata")


def _check_spacing(time: np.ndarray, dt: np.ndarray, within: np.ndarray, spacing: float, path: str) -> None:
    """Consecutive rows of one step (``within``: (N − 1,) bool, row i + 1 of row i's step) one SYNC apart:
    within :data:`MAX_SPACING_JITTER` of the recording's median spacing. The recorder writes a row every
    cycle (a missed TPDO as the value held from the cycle before), so a longer step is a row missing
    (deleted, or a decoded log's cycle skipped as incomplete) and a shorter one a time off the SYNC grid;
    either puts the step's velocities and accelerations at the wrong time. A count per step cannot see a
    few such rows (:data:`ROW_SHARE_TOLERANCE`). Between two steps a recording may lack the steps it was
    cut down to leave out; each step is filtered and fitted on its own rows."""
    off = np.flatnonzero(within & (np.abs(dt - spacing) > MAX_SPACING_JITTER * spacing))
    if not len(off):
        return
    i = int(off[0])
    cycles = dt[i] / spacing
    lost = int(round(cycles)) - 1
    what = (f"{lost} row(s) missing before it" if lost >= 1 and abs(cycles - (lost + 1)) <= 0.25
            else "its time off the SYNC grid")                 # a whole number of cycles, or not
    raise RecordingError(f"{path}:{i + 3}: time {float(time[i + 1])!r} s follows {float(time[i])!r} s, "
                         f"the rows are {spacing:.6g} s apart: {what} ({len(off)} such place(s) in the file; "
                         "rows deleted, or cycles a decode skipped as incomplete)")


def check_ranges(signals: Signals, max_torque: float, steering_limit: float, path: str) -> None:
    """Every torque actual within the drives' peak torque and every steering angle within the stops.

    A drive limits its torque to ``max_torque`` (0x6072, motor side); its torque actual can read above it
    only by measurement noise (:data:`TORQUE_OVER_MAX`). The steering units turn between mechanical stops
    at ±``steering_limit``; the sensor can read beyond them only by its noise (:data:`ANGLE_OVER_LIMIT`).
    A value past either is another unit (per mille not converted, degrees) or another vehicle's data
    sheet, which would identify a vehicle hundreds of times heavier without a word.

    Raises:
        RecordingError: names the line, the column, the value and the limit."""
    checks = [(f"motor_torque_{w}", signals.motor_torque[:, j], (1 + TORQUE_OVER_MAX) * max_torque,
               f"the data sheet's max_torque {max_torque:g} N m (motor side)") for j, w in enumerate(WHEELS)]
    checks += [(f"alpha_{side}", signals.alpha[:, j], steering_limit + ANGLE_OVER_LIMIT,
                f"the steering stops at ±{steering_limit:g} rad") for j, side in enumerate("lr")]
    for column, values, bound, limit in checks:
        over = np.flatnonzero(np.abs(values) > bound)
        if len(over):
            i = int(over[0])
            raise RecordingError(f"{path}:{i + 2}: column '{column}' is {float(values[i])!r}, beyond {limit} "
                                 f"({len(over)} row(s)): another unit, or a data sheet of another vehicle")


def configuration_error(alpha: np.ndarray, k: int, geometry) -> np.ndarray:
    """Distance (rad) of steering angles ``alpha`` (N, 2) from the fixed configuration of mode k = 3 or 4
    of (9), max |α − :func:`.kinematics.mode_alpha`| per row, shape (N,): each wheel's heading error."""
    return np.max(np.abs(alpha - kinematics.mode_alpha(k, geometry)), axis=1)


def check_modes(signals: Signals, geometry, path: str) -> None:
    """Every mode-3 and mode-4 step's steering holds its mode's fixed configuration (9).

    The rows of such a step are the mode's only where the steering lies on its configuration: the median
    of :func:`configuration_error` over every :data:`MODE_WINDOW` of the step's rows (a shorter step: all
    of them; windows a tenth of one apart) must be at most :data:`MAX_CONFIGURATION_ERROR`. Mode 1 steers
    freely; mode 2's distance from the ICR manifold is no slip angle (near the stops a small heading error
    of the inner wheel moves α_v, and the distance, by far more: 0.46 rad in an arc of a vehicle with
    both-joint Stribeck friction at the realistic range's end), so neither is checked, nor are the rows
    of a decoded log without campaign steps (k = 0).

    Raises:
        RecordingError: names the line and time where the first such window starts, the step, its mode
            and the median error.
    """
    time = np.asarray(signals.time, dtype=float)
    if len(time) < 2:
        return
    width = max(1, int(round(MODE_WINDOW / float(np.median(np.diff(time))))))
    step = np.asarray(signals.step)
    starts = np.flatnonzero(np.r_[True, step[1:] != step[:-1]])
    for first, stop in zip(starts, np.r_[starts[1:], len(time)]):
        k = int(signals.k[first])
        if k not in (3, 4):
            continue
        error = configuration_error(np.asarray(signals.alpha[first:stop], dtype=float), k, geometry)
        w = min(width, len(error))
        hop = max(1, w // 10)
        medians = np.median(np.lib.stride_tricks.sliding_window_view(error, w)[::hop], axis=1)
        off = np.flatnonzero(medians > MAX_CONFIGURATION_ERROR)
        if len(off):
            j = int(first + off[0] * hop)
            median = float(medians[off[0]])
            raise RecordingError(
                f"{path}:{j + 2}: the steering angles of step '{step[first]}' (mode {k}) lie "
                f"{median:.3g} rad from the mode's configuration (median over "
                f"{w * float(np.median(np.diff(time))):.3g} s from t = {time[j]:.3f} s; at most "
                f"{MAX_CONFIGURATION_ERROR:g} rad): these rows are not that step's (a log decoded with "
                "another campaign's metadata, or step labels shifted), or the data sheet's geometry (l, b) is "
                "not this vehicle's")


def velocity_conventions(v: np.ndarray) -> np.ndarray:
    """(3, N − 1): a drive's velocity actual (N,) at the end of each cycle, at its start, and their mean,
    the three ways a drive may time-stamp 0x606C against the position change x_t − x_{t−1} (multiply by
    T_s to compare)."""
    v = np.asarray(v, dtype=float)
    return np.stack([v[1:], v[:-1], 0.5 * (v[1:] + v[:-1])])


def _robust_r2(d: np.ndarray, rate: np.ndarray) -> float:
    """1 − (median |d − rate| / median |rate|)² over the rows where either moves: R² with medians for
    mean squares, so that the few glitches :mod:`.spikes` repairs later do not decide it (a frozen
    signal: 0, a reversed one: −3, agreeing ones: near 1)."""
    moving = (d != 0) | (rate != 0)
    scale = float(np.median(np.abs(rate[moving]))) if moving.any() else 0.0
    if scale == 0.0:
        return 1.0 if not np.any(d[moving]) else -np.inf
    return 1.0 - (float(np.median(np.abs(d[moving] - rate[moving]))) / scale) ** 2


def check_drives(signals: Signals, path: str) -> None:
    """Each drive's position, velocity and torque actual are alive and agree with each other, over a
    recording of at least :data:`MIN_SPAN` (a shorter one is too little evidence either way).

    - position and velocity: the position's change over a cycle (consecutive rows only) against T_s
      times the velocity actual at either end of it or their mean (the drive's convention), robust R²
      (:func:`_robust_r2`) ≥ :data:`MIN_POSITION_VELOCITY_R2`;
    - torque actual: not constant, and its rank correlation with the commanded torque at least
      :data:`MIN_TORQUE_CORRELATION` (skipped where the recording holds no commanded torque).

    Raises:
        RecordingError: names the column and the figure that fails.
    """
    time = np.asarray(signals.time, dtype=float)
    if len(time) < 3 or time[-1] - time[0] < MIN_SPAN:
        return
    dt = np.diff(time)
    ts = float(np.median(dt))
    consecutive = np.abs(dt - ts) <= MAX_SPACING_JITTER * ts
    for j, wheel in enumerate(WHEELS):
        x, v = signals.motor_position[:, j], signals.motor_velocity[:, j]
        d = np.diff(x)[consecutive]
        if not np.any(d) and not np.any(v):
            raise RecordingError(f"{path}: motor_position_{wheel} and motor_velocity_{wheel} never change: "
                                 f"drive {wheel} did not report (or its wheel never turned)")
        r2 = max(_robust_r2(d, ts * rate[consecutive]) for rate in velocity_conventions(v))
        if r2 < MIN_POSITION_VELOCITY_R2:
            raise RecordingError(f"{path}: motor_position_{wheel} does not move with motor_velocity_{wheel} "
                                 f"(R² = {r2:.2f} of the position's change per cycle against T_s × velocity, "
                                 f"at least {MIN_POSITION_VELOCITY_R2} expected): a frozen encoder, a reversed "
                                 "polarity or another unit in one of them")
        torque, command = signals.motor_torque[:, j], signals.motor_torque_cmd[:, j]
        if np.ptp(torque) == 0:
            raise RecordingError(f"{path}: motor_torque_{wheel} is {float(torque[0])!r} N m in every row: drive "
                                 f"{wheel} did not report its torque actual")
        if np.ptp(command) > 0:
            rho = float(spearmanr(torque, command)[0])
            if rho < MIN_TORQUE_CORRELATION:
                raise RecordingError(f"{path}: motor_torque_{wheel} does not follow the commanded torque "
                                     f"(rank correlation {rho:.2f}, at least {MIN_TORQUE_CORRELATION} "
                                     "expected): a reversed torque polarity or another drive's value")


__all__ = ["check_coverage", "check_drives", "check_ranges", "check_modes", "configuration_error",
           "velocity_conventions", "MIN_SPAN",
           "ROW_TOLERANCE", "MIN_POSITION_VELOCITY_R2", "MIN_TORQUE_CORRELATION"]
