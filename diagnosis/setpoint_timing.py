"""The drives' torque timing from the bus: a torque report lag measured against the set-point, and the
actuator delay that the ground's fit sees only net of it.

The ground's data show one timing: how far the motion lags the reported torque. A torque report lag
(0x6077 late, effect ``torque_report_lag``) moves that one way and an actuator delay (the torque acting
late, ``actuator_delay``) the other, so the fit sees their difference: a 4 ms report lag beside an 8 ms
delay reads as a 4 ms delay, and beside a 4 ms delay as nothing. The bus holds what tells them apart:
the master's own set-point (0x6071). By the convention (docs/conventions.md, "Torque timing") a drive
reports with SYNC j the set-point it latched at SYNC j, so a lag of 0x6077 behind 0x6071
(:func:`qomni.ident.setpoint_lag.setpoint_lag`) is the report lag itself, measured without a model, while
an actuator delay leaves the report on time.

Rule (:func:`timing_by_setpoint`). Where the set-point lag δ_r is there (z ≥ :data:`SETPOINT_Z`) and at
least half a cycle (nearer the previous cycle's set-point than its own), the report lag is named with δ_r
as its magnitude. The net shift s the ground's data hold (as a report lag: the named report lag's fitted
magnitude, minus the named delay's, or else the first round's report-lag fit) then puts the actuator delay
at δ_r − s, with the two σ combined: a named delay's magnitude becomes that, and an unnamed one is named
where it is there by the same z and at least half a cycle. Measured effects are not added to the model:
the ground's fit of the net shift stays what the model holds.

Where the run records the set-point and the measurement bounds the report lag under the shortest the
hypothesis names, the ground's data are not asked for one (:func:`report_lag_ruled_out`): the report lag
is what the bus measures, and a net shift of the other sign than an actuator delay's would put the torque
on the wheels before the master commanded it. Without the rule the report-lag hypothesis took up other
effects' fast misfit: beside steering-joint Stribeck friction it was named at 1.0–7.3 ms where the bus
read 0.000–0.002 ms (σ 0.0008 ms).
"""
from __future__ import annotations

import math
from dataclasses import replace

from .hypotheses.base import Z_95, Magnitude, interval_95
from .hypotheses.torque_report_lag import SHORTEST_CYCLES

#: z of the set-point lag (and of the delay derived from it) for naming: p = 10⁻³ two-sided.
SETPOINT_Z = 3.29
#: Shortest lag or delay named, in cycles of T_s.
MIN_CYCLES = 0.5

LAG, DELAY = "torque_report_lag", "actuator_delay"


def _sd(magnitude: Magnitude) -> float:
    """σ of a magnitude from its 95 % interval."""
    return abs(magnitude.ci[1] - magnitude.ci[0]) / (2 * Z_95)


def _measured(cand, value: float, sd: float, note: str, named_here: bool = True):
    """``cand`` with the measured magnitude and a note; ``named_here``: named by the measurement (its fit
    stays out of the model), else an effect the ground's fit named, re-sized."""
    return replace(cand, magnitude=replace(cand.magnitude, value=value, ci=interval_95(value, sd)),
                   significant=True, measured="set-point" if named_here else cand.measured,
                   notes=[*cand.notes, note])


def report_lag_ruled_out(setpoint, cycle_time: float) -> bool:
    """Whether the bus rules out a report lag that the ground's data would be asked for: the run records
    the set-point (``setpoint`` not None) and the measured lag's 95 % upper bound (δ_r + 1.96 σ) is under
    the shortest lag the hypothesis names (``hypotheses.torque_report_lag.SHORTEST_CYCLES``, 0.3 cycles of
    ``cycle_time``, s).

    The ground's data see only the net shift between the motion and the reported torque, the report lag
    less the actuator delay. With the report lag measured at δ_r, a net shift s would put the delay at
    δ_r − s, below zero for any report lag s the hypothesis names: a torque acting before it was
    commanded, which no drive does. So the hypothesis is not fitted. A measurement too uncertain to bound
    the lag (a short or noisy recording) rules nothing out."""
    return setpoint is not None and setpoint.value + Z_95 * setpoint.std < SHORTEST_CYCLES * cycle_time


def timing_by_setpoint(candidates: list, accepted: list, setpoint, cycle_time: float) -> list:
    """``accepted`` with the report lag and actuator delay the set-point measurement names or re-sizes
    (module docstring); unchanged where ``setpoint`` (a :class:`qomni.ident.setpoint_lag.SetpointLag`) is
    None or shows no lag.

    Args:
        candidates: the first round's fitted hypotheses (:class:`.fit.Candidate`).
        accepted: the effects named so far, in order.
        setpoint: the set-point lag of the diagnosed data (after the model's own torque lag).
        cycle_time: T_s (s).
    Returns:
        The new list of named effects: the ones before (a re-sized one in its place), then the ones the
        measurement names.
    """
    if setpoint is None or setpoint.z() < SETPOINT_Z or setpoint.value < MIN_CYCLES * cycle_time:
        return accepted
    named = {c.hypothesis.name: c for c in accepted}
    first = {c.hypothesis.name: c for c in candidates if c.hypothesis.name in (LAG, DELAY)}
    if LAG in named or DELAY in named:
        net = (named[LAG].magnitude.value if LAG in named else 0.0) \
            - (named[DELAY].magnitude.value if DELAY in named else 0.0)
        net_sd = math.hypot(*(_sd(named[n].magnitude) for n in (LAG, DELAY) if n in named), 0.0)
    elif LAG in first:
        net, net_sd = first[LAG].magnitude.value, _sd(first[LAG].magnitude)
    else:
        net, net_sd = setpoint.value, 0.0
    delay = setpoint.value - net
    delay_sd = math.hypot(net_sd, setpoint.std)
    ms = 1e3
    bus = (f"measured on the bus: the torque actual (0x6077) follows the set-point (0x6071) by "
           f"{setpoint.value * ms:.2f} ± {setpoint.std * ms:.2f} ms ({setpoint.cycles:.2f} cycles)")
    motion = f"the motion lags the reported torque by {-net * ms:.2f} ms"
    out = []
    for c in accepted:
        if c.hypothesis.name == LAG:
            c = _measured(c, setpoint.value, setpoint.std, f"{bus}; {motion}", named_here=False)
        elif c.hypothesis.name == DELAY:
            c = _measured(c, delay, delay_sd, f"{motion}, and {bus}: the torque acts {delay * ms:.2f} ± "
                                              f"{delay_sd * ms:.2f} ms after the set-point", named_here=False)
        out.append(c)
    source = first.get(LAG)
    if LAG not in named and source is not None:
        out.append(_measured(source, setpoint.value, setpoint.std, f"named by the set-point: {bus}; {motion}"))
    source = first.get(DELAY)
    if DELAY not in named and source is not None and delay >= MIN_CYCLES * cycle_time \
            and delay >= SETPOINT_Z * delay_sd:
        out.append(_measured(source, delay, delay_sd,
                             f"named by the set-point: {bus}, and {motion}, so the torque acts "
                             f"{delay * ms:.2f} ± {delay_sd * ms:.2f} ms after the set-point"))
    return out


__all__ = ["SETPOINT_Z", "report_lag_ruled_out", "timing_by_setpoint"]
