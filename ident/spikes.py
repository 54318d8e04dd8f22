"""Isolated spikes in recorded signals, found against their neighbours and repaired before filtering.

A glitch on the way to ``signals.csv`` (a corrupted frame decoded as a valid value, a reading saturated
for a cycle, a row of zeros for a dropped sample) puts a sample far from its neighbours. The zero-phase
filter and the differentiation of the paper's section 5 spread one such sample over ≈ 4/(ω_g T_s) = 50
rows of Θ̂₁ and τ̂, where no row-wise estimator isolates it again; in the raw samples it stands alone.

The test, per signal column x (N,) (:func:`find_spikes`):

1. First differences d_t = x_t − x_{t−1}. A spike of height s at t is the pair (+s, −s) in d; a step of
   the signal (a torque set-point step, the start of a campaign step) is one value; smooth motion,
   turning points included, keeps d smooth.
2. Deviation u_t = d_t − (running median of d over 2H + 1 samples): the median follows steps of d (a
   change of acceleration) and ignores up to H outliers.
3. Local scale σ_t of d's noise = 1.4826·MAD of the second differences about their running median
   over 2W + 1 samples, / √3 (white noise: σ(Δ²x) = √3 σ(d)), at least the column's global robust scale
   and its quantum (the smallest nonzero change between samples: an encoder count, the torque
   actual's resolution), so a quantised signal at rest, whose MAD is 0, is not read as noise-free.
4. Differences with |u_t| > K σ_t are flagged. Flagged differences no more than G samples apart form a
   cluster d_i … d_k (a first pass flags, a second takes the running median and σ over d with the
   flagged values interpolated, since a trending d's median shifts a rank per outlier in its window);
   the samples x_i … x_{k−1} inside it are corrupt when the cluster returns to the trend,
   |x_k − x_{i−1} − (k − i + 1)·(d_{i−1} + d_{k+1})/2| ≤ K σ √(n + n²/2), n = k − i + 1 (exact under
   constant acceleration). A cluster that does not return is a step of the signal and is kept.
5. A drive's position and velocity actual are redundant (the velocity is the position's rate): a
   cluster in either is corrupt only where the two disagree (:func:`_position_velocity_disagreement`).
   A motor crossing a backlash gap and rebounding within a few cycles leaves the position's trend and
   returns like a glitch, but its velocity moves with it, and it is kept. The torque actual follows the
   master's command (:func:`_torque_command_disagreement`): a stick-slip torque spike the controller
   commanded is kept (strong Stribeck friction and a 20 ms actuator delay gave 1–5 such samples per
   quick campaign without this test). On the emulator's effects at both ends of their realistic ranges
   (37 quick campaigns, ``benchmarks/blind_suite.py --range-ends``) two samples in all are changed, by
   less than 0.02 N m each (a torque reversal within 4 cycles, 8.5 σ off its command); the steering
   angles, which have no partner, not one.

Corrupt samples are replaced by the straight line between x_{i−1} and x_k (:func:`repair_spikes`), and
the count per column is reported. K = 8: under Gaussian noise a deviation beyond 8 σ has probability
1.2·10⁻¹⁵ per sample, so a clean recording is left as it is (``tests/test_spikes.py``; the prototype's
quick and full campaigns: no sample changed), while a glitch worth repairing (one that moves a
parameter) is hundreds of σ high. More than :data:`MAX_CORRUPT_FRACTION` of a column corrupt is not a few glitches:
:class:`~.recording.RecordingError`.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.ndimage import median_filter

from .plausibility import velocity_conventions
from .recording import WHEELS, RecordingError, Signals

#: Half-width of the running median of the differences (samples), and the longest burst of corrupt
#: samples the test is made for (bursts of 1…H are found in ``tests/test_spikes.py``).
H = 5
#: Half-width of the window of the local scale (samples): 0.2 s at 500 Hz, a few periods of the
#: filter's 6 Hz band, so the scale follows the noise of each motion phase.
W = 50
#: Flagged differences at most G samples apart belong to one cluster (a burst of up to G samples).
G = H
#: Flagging passes, each with the trend taken over the differences the last one did not flag.
PASSES = 2
#: Threshold in local σ (module docstring).
K = 8.0
#: MAD → σ of a normal distribution.
MAD_TO_SIGMA = 1.4826
#: A column with more corrupt samples than this share is refused rather than repaired.
MAX_CORRUPT_FRACTION = 0.05

#: The columns tested: what the drives put on the bus (the commanded torque is the master's own value).
COLUMNS = ("alpha", "motor_position", "motor_velocity", "motor_torque")


@dataclass(frozen=True)
class SpikeReport:
    """Corrupt samples found per ``signals.csv`` column (``"motor_torque_fr"`` …), the steps kept, and whether the
    corrupt samples were repaired."""

    corrupt: dict
    steps_kept: dict
    samples: int
    repaired: bool = True

    @property
    def total(self) -> int:
        return int(sum(self.corrupt.values()))

    def to_json_dict(self) -> dict:
        return {"repaired": self.repaired, "corrupt_samples": dict(self.corrupt), "total_corrupt": self.total,
                "samples": self.samples, "steps_kept": dict(self.steps_kept),
                "test": f"first differences against their running median ({2 * H + 1} samples), "
                        f"|u| > {K:g} local robust sigma, clusters returning to the trend are corrupt"}


def _quantum(d: np.ndarray) -> float:
    """The smallest nonzero change between successive samples: a quantised signal's resolution (a
    glitch's changes are large, so it does not shrink this the way a spike's value beside the others
    would shrink the smallest gap between distinct values)."""
    moved = np.abs(d[d != 0])
    return float(moved.min()) if len(moved) else 0.0


def find_spikes(x: np.ndarray, disagrees: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Corrupt samples of one signal (N,) by the test of the module docstring.

    ``disagrees`` (N,) bool, where the signal has a redundant partner (a position and its velocity
    actual): the samples where the two disagree. A cluster is then corrupt only if one of its samples
    disagrees; one its partner corroborates is motion (a backlash gap crossed in a few cycles) and kept.

    Returns (mask (N,) bool of corrupt samples, number of steps found and kept)."""
    x = np.asarray(x, dtype=float)
    n = len(x)
    corrupt = np.zeros(n, dtype=bool)
    if n < 2 * H + 3:
        return corrupt, 0
    d = np.diff(x)                          # d[j] = x[j+1] - x[j]
    # from the recorded differences: interpolated ones are no resolution of the sensor
    quantum = max(_quantum(d), 1e-12 * max(1.0, float(np.max(np.abs(x)))))
    flagged = np.zeros(len(d), dtype=bool)
    for _ in range(PASSES):
        # the median of a trending d shifts by a rank per outlier in its window: take it over the
        # differences with the ones flagged so far interpolated
        clean = _repaired(d, flagged) if flagged.any() else d
        trend = median_filter(clean, size=2 * H + 1, mode="nearest")
        sigma = _local_scale(clean, quantum)
        flagged = np.abs(d - trend) > K * sigma
    steps = 0
    idx = np.flatnonzero(flagged)
    start = 0
    while start < len(idx):
        end = start
        while end + 1 < len(idx) and idx[end + 1] - idx[end] <= G:
            end += 1
        i, k = idx[start], idx[end]             # differences d[i..k]: samples x[i+1..k] inside
        span = k - i + 1
        # the change across the cluster against the trend's, interpolated between the differences
        # just outside it (exact under constant acceleration)
        before, after = d[max(i - 1, 0)], d[min(k + 1, len(d) - 1)]
        net = x[k + 1] - x[i] - span * 0.5 * (before + after)
        tolerance = K * float(np.max(sigma[i:k + 1])) * np.sqrt(span + 0.5 * span ** 2)
        witnessed = disagrees is None or bool(disagrees[i:k + 2].any())
        if span >= 2 and abs(net) <= tolerance and witnessed:
            corrupt[i + 1:k + 1] = True
        else:
            steps += 1
        start = end + 1
    return corrupt, steps


def _local_scale(d: np.ndarray, quantum: float) -> np.ndarray:
    """(len(d),) local σ of the differences' noise, from the second differences: under white noise of σ
    in x, d has σ√2 and Δ²x (√6)σ about their local levels, so σ_d = σ(Δ²x)/√3. The second differences
    are used because a fast motion makes d itself trend faster than its noise, where the running median
    of d sits on the sample itself and the MAD of d − median reads far less than the noise."""
    dd = np.diff(d)
    a = np.abs(dd - median_filter(dd, size=2 * H + 1, mode="nearest"))
    floor = max(MAD_TO_SIGMA * float(np.median(a)) / np.sqrt(3.0), quantum)
    local = MAD_TO_SIGMA * median_filter(a, size=2 * W + 1, mode="nearest") / np.sqrt(3.0)
    return np.maximum(np.concatenate([local[:1], local]), floor)


def _position_velocity_disagreement(signals: Signals) -> np.ndarray:
    """(N, 4) bool: samples where a drive's position and velocity actual disagree.

    The position's change over a cycle, d_t = x_t − x_{t−1}, is T_s times the velocity actual at t, at
    t − 1 or their mean, depending on how the drive derives and time-stamps 0x606C: the one closest to
    d over the run (median) is the drive's. A difference disagrees when it is more than K σ_c from it,
    σ_c its robust scale over the run (at least the position's quantum), and so do the two samples
    that make it: a glitch in either signal leaves the other behind, a real fast motion moves both."""
    x, v = np.asarray(signals.motor_position, float), np.asarray(signals.motor_velocity, float)
    out = np.zeros(x.shape, dtype=bool)
    if len(x) < 3:
        return out
    ts = float(np.median(np.diff(signals.time)))
    d = np.diff(x, axis=0)
    for j in range(x.shape[1]):
        gaps = np.abs(d[:, j, None] - ts * velocity_conventions(v[:, j]).T)   # per d_t, t = 1..N-1
        bad = _far(gaps[:, int(np.argmin(np.median(gaps, axis=0)))], _quantum(d[:, j]))   # drive's convention
        out[1:, j] |= bad                                               # sample t ends d_t
        out[:-1, j] |= bad                                              # sample t-1 starts it
    return out


#: s: the longest lag of a drive's torque actual behind its command that a real excursion of the command
#: is looked for at (the actuator delay's realistic range ends at 20 ms, docs/effects.md).
TORQUE_COMMAND_LAG = 0.025


def _torque_command_disagreement(signals: Signals) -> np.ndarray:
    """(N, 4) bool: samples where a drive's torque actual is far from every command it could be following.

    The current loop follows the master's command (``motor_torque_cmd``), late by the drive's delay: the
    torque actual at t is compared with the commands from t − :data:`TORQUE_COMMAND_LAG` to t + 2 cycles;
    a sample disagrees when the closest is more than K σ_τ away, σ_τ the robust scale of that distance
    over the run (at least the torque's quantum). A stick-slip torque spike the controller commanded is
    in the command too, and kept; a glitch is not. Without a recorded command (constant) every sample
    counts as disagreeing: the plain test decides."""
    torque, command = np.asarray(signals.motor_torque, float), np.asarray(signals.motor_torque_cmd, float)
    n = len(torque)
    out = np.ones(torque.shape, dtype=bool)
    if n < 3:
        return out
    lags = range(-2, int(round(TORQUE_COMMAND_LAG / float(np.median(np.diff(signals.time))))) + 1)
    for j in range(torque.shape[1]):
        c = command[:, j]
        if np.ptp(c) == 0:
            continue
        gap = np.full(n, np.inf)
        for lag in lags:                      # torque at t against command at t - lag
            if lag >= 0:
                gap[lag:] = np.minimum(gap[lag:], np.abs(torque[lag:, j] - c[:n - lag]))
            else:
                gap[:lag] = np.minimum(gap[:lag], np.abs(torque[:lag, j] - c[-lag:]))
        out[:, j] = _far(gap, _quantum(np.diff(torque[:, j])))
    return out


def _far(gap: np.ndarray, quantum: float) -> np.ndarray:
    """Where a distance between partners is more than K times its robust scale over the run (1.4826·its
    median: most samples agree), at least the signal's quantum."""
    return gap > K * max(MAD_TO_SIGMA * float(np.median(gap)), quantum)


def _column_name(name: str, j: int) -> str:
    """The ``signals.csv`` column of block ``name``'s column j (``alpha_l``, ``motor_torque_fr`` …)."""
    return ("alpha_l", "alpha_r")[j] if name == "alpha" else f"{name}_{WHEELS[j]}"


def _repaired(x: np.ndarray, corrupt: np.ndarray) -> np.ndarray:
    good = ~corrupt
    out = x.copy()
    idx = np.arange(len(x))
    out[corrupt] = np.interp(idx[corrupt], idx[good], x[good])
    return out


def repair_spikes(signals: Signals, source: str = "signals", repair: bool = True) -> tuple[Signals, SpikeReport]:
    """The signals with the corrupt samples of :data:`COLUMNS` interpolated, and what was found.

    Args:
        signals: a recording (rows in time order, as :func:`.recording.read_signals` returns them).
        source: the file named in errors.
        repair: false returns ``signals`` unchanged with the report of what was found.
    Raises:
        RecordingError: more than :data:`MAX_CORRUPT_FRACTION` of a column is corrupt (names the column).
    """
    repaired, kept, changes = {}, {}, {}
    disagreement = _position_velocity_disagreement(signals)
    torque_disagreement = _torque_command_disagreement(signals)
    for name in COLUMNS:
        block = np.array(getattr(signals, name), dtype=float, copy=True)
        for j in range(block.shape[1]):
            partner = (disagreement[:, j] if name in ("motor_position", "motor_velocity")
                       else torque_disagreement[:, j] if name == "motor_torque" else None)
            corrupt, steps = find_spikes(block[:, j], partner)
            key = _column_name(name, j)
            count = int(corrupt.sum())
            if count > MAX_CORRUPT_FRACTION * len(block):
                raise RecordingError(f"{source}: column {key}: {count} of {len(block)} samples stand apart "
                                     f"from their neighbours (more than {MAX_CORRUPT_FRACTION:.0%}); "
                                     "the recording is corrupt beyond repairing single glitches")
            repaired[key], kept[key] = count, steps
            if count:
                block[:, j] = _repaired(block[:, j], corrupt)
        changes[name] = block
    report = SpikeReport(repaired, kept, len(signals), repair)
    return (replace(signals, **changes) if repair else signals), report


__all__ = ["SpikeReport", "find_spikes", "repair_spikes", "K", "H", "W", "MAX_CORRUPT_FRACTION"]
