"""Decoded signals of a campaign, recorded as they arrive and read back for identification.

``signals.csv`` holds one row per SYNC cycle. Column headers carry their unit in brackets, e.g.
``motor_torque_fl [N m motor]``. Rows are flushed at the end of every campaign step (and on close), so an
interrupted campaign keeps everything it recorded up to the interruption.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from qomni.conventions import WHEELS

#: (name, unit) of every column of signals.csv, in order.
COLUMNS: tuple[tuple[str, str], ...] = (
    ("time", "s"),
    ("step", "-"),
    ("k", "-"),
    ("alpha_l", "rad"),
    ("alpha_r", "rad"),
    *((f"motor_position_{w}", "rad motor") for w in WHEELS),
    *((f"motor_velocity_{w}", "rad/s motor") for w in WHEELS),
    *((f"motor_torque_{w}", "N m motor") for w in WHEELS),
    *((f"motor_torque_cmd_{w}", "N m motor") for w in WHEELS),
)


class RecordingError(ValueError):
    """A signals file is unreadable: says which file, line and column."""


@dataclass
class Signals:
    """Recorded signals; every array has length N (one entry per SYNC cycle).

    Attributes:
        time: (N,) s.
        step: (N,) str, campaign step name (e.g. ``steer_left``).
        k: (N,) int, motion mode the step runs in (paper (9)).
        alpha: (N, 2) steering angles α_l, α_r [rad].
        motor_position: (N, 4) [rad, motor side], fl, rl, fr, rr.
        motor_velocity: (N, 4) [rad/s, motor side].
        motor_torque: (N, 4) torque actual [N m, motor side].
        motor_torque_cmd: (N, 4) commanded torque [N m, motor side].
    """

    time: np.ndarray
    step: np.ndarray
    k: np.ndarray
    alpha: np.ndarray
    motor_position: np.ndarray
    motor_velocity: np.ndarray
    motor_torque: np.ndarray
    motor_torque_cmd: np.ndarray

    def __len__(self) -> int:
        return len(self.time)

    def select(self, mask: np.ndarray) -> "Signals":
        """The rows where ``mask`` (N,) bool is true."""
        return Signals(**{name: getattr(self, name)[mask] for name in self.__dataclass_fields__})

    def of_step(self, name: str) -> "Signals":
        """The rows of one campaign step.

        Raises:
            KeyError: the recording has no such step.
        """
        mask = self.step == name
        if not mask.any():
            raise KeyError(f"no rows for step '{name}' (steps: {self.steps()})")
        return self.select(mask)

    def steps(self) -> list[str]:
        """Step names in the order they were run."""
        names, first = np.unique(self.step, return_index=True)
        return [str(n) for n in names[np.argsort(first)]]


def _floats(values) -> list[float]:
    """Python floats of a 1-D array or sequence."""
    return np.asarray(values, dtype=float).tolist()


def header() -> list[str]:
    return [f"{name} [{unit}]" for name, unit in COLUMNS]


class SignalWriter:
    """Writes one row per cycle to a new ``signals.csv``; use as a context manager.

    Raises:
        RecordingError: the file exists already (a recording is never appended to an old run).
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        try:
            self._file = open(self.path, "x", newline="")
        except FileExistsError:
            raise RecordingError(f"{self.path} exists: a recording is never appended to an old run; "
                                 "choose a new run directory (or --force to replace it)") from None
        self._csv = csv.writer(self._file)
        self._csv.writerow(header())
        self.rows = 0
        self._held: list[list] | None = None

    def write(self, step: str, k: int, measurement, motor_torque_cmd) -> None:
        """Record one cycle.

        Args:
            step: campaign step name.
            k: motion mode (paper (9)).
            measurement: the client's measurement (time, alpha (2,), motor_position, motor_velocity,
                motor_torque, each (4,) in SI on the motor side).
            motor_torque_cmd: (4,) commanded motor torque in N m.
        """
        m = measurement
        # Python floats (``tolist``): the csv module writes a float as its repr, the shortest text that
        # reads back to the same double; a numpy scalar would be written as its own repr.
        row = [float(m.time), step, int(k), *_floats(m.alpha), *_floats(m.motor_position),
               *_floats(m.motor_velocity), *_floats(m.motor_torque), *_floats(motor_torque_cmd)]
        if self._held is not None:
            self._held.append(row)
            return
        self._csv.writerow(row)
        self.rows += 1

    def hold(self) -> None:
        """Keep the following rows back (in memory, as written) until :meth:`release`: a stretch whose
        step name is decided only at its end (a campaign step that may turn out to be a limit cycle)."""
        if self._held is None:
            self._held = []

    def release(self, step: str | None = None) -> None:
        """Write the held rows in their order, under ``step`` instead of their own step names if given."""
        held, self._held = self._held or [], None
        for row in held:
            if step is not None:
                row[1] = step
            self._csv.writerow(row)
        self.rows += len(held)

    def flush(self) -> None:
        self._file.flush()

    def close(self) -> None:
        if not self._file.closed:
            self.release()
            self._file.close()

    def __enter__(self) -> "SignalWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _check_order(path: Path, time: np.ndarray) -> None:
    """One row per SYNC in the order recorded: time (the SYNC count × T_s) increases strictly. A step
    reversed in time, rows copied, or two runs in one file fail here."""
    back = np.flatnonzero(np.diff(time) <= 0)
    if len(back):
        i = int(back[0]) + 1
        raise RecordingError(f"{path}:{i + 2}: time {float(time[i])!r} s does not increase (previous row "
                             f"{float(time[i - 1])!r} s): rows reversed, duplicated or from two runs")


def _check_modes(path: Path, k: np.ndarray) -> None:
    """Column k holds the paper's motion mode, 1 to 4, or 0 on the rows of a decoded log outside any
    step of its metadata (step ``recorded``)."""
    bad = np.flatnonzero((k != np.round(k)) | (k < 0) | (k > 4))
    if len(bad):
        i = int(bad[0])
        raise RecordingError(f"{path}:{i + 2}: column 'k [-]' is {float(k[i])!r}, not a motion mode (1 to 4, or 0 "
                             "outside the campaign's steps)")


def read_signals(path: str | Path) -> Signals:
    """Read ``signals.csv``.

    Raises:
        FileNotFoundError: no such file.
        RecordingError: wrong header, a short row, a value that is not a finite number, time not
            increasing or a motion mode k that is not one (file and line given).
    """
    path = Path(path)
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        raise RecordingError(f"{path}: empty file")
    expected = header()
    if rows[0] != expected:
        missing = [h for h in expected if h not in rows[0]]
        raise RecordingError(f"{path}:1: unexpected header; missing columns {missing}")
    body = rows[1:]
    if body and len(body[-1]) != len(expected):
        body = body[:-1]  # a campaign killed mid-write leaves a truncated last line
    if not body:
        raise RecordingError(f"{path}: no data rows")
    numeric = np.empty((len(body), len(expected) - 1))
    steps = []
    for line, row in enumerate(body, start=2):
        if len(row) != len(expected):
            raise RecordingError(f"{path}:{line}: {len(row)} fields, expected {len(expected)}")
        steps.append(row[1])
        for col, text in enumerate(row):
            if col == 1:
                continue
            try:
                value = float(text)
            except ValueError:
                raise RecordingError(f"{path}:{line}: column '{expected[col]}' is not a number: "
                                     f"{text!r}") from None
            if not math.isfinite(value):
                raise RecordingError(f"{path}:{line}: column '{expected[col]}' is {text}")
            numeric[line - 2, col - 1 if col > 1 else 0] = value
    col = {name: i - 1 if i > 1 else 0 for i, (name, _) in enumerate(COLUMNS)}
    _check_order(path, numeric[:, col["time"]])
    _check_modes(path, numeric[:, col["k"]])

    def block(prefix: str) -> np.ndarray:
        return numeric[:, [col[f"{prefix}_{w}"] for w in WHEELS]]

    return Signals(
        time=numeric[:, col["time"]],
        step=np.array(steps),
        k=numeric[:, col["k"]].astype(int),
        alpha=numeric[:, [col["alpha_l"], col["alpha_r"]]],
        motor_position=block("motor_position"),
        motor_velocity=block("motor_velocity"),
        motor_torque=block("motor_torque"),
        motor_torque_cmd=block("motor_torque_cmd"),
    )
