"""The library of named physical hypotheses: unmodelled effects as nested extensions of the paper's
model, one plug-in module per effect (mirroring ``emulator/effects``) behind one contract
(:class:`~.base.Hypothesis`).

Each hypothesis adds columns Φ_e to a channel so that the residual of the base model is explained as
``r ≈ Θ̂₁ δp + Φ_e θ_e`` (θ_e = 0 is the paper's model). Columns are built from what the vehicle puts
on the bus (recorded torques, encoder and steering-sensor angles, odometry) and the base model's
parameters — never from the emulator. Non-linear parameters (a delay, a Stribeck velocity) are
profiled over a grid; everything else enters linearly.

Sign convention: the residual is τ̂ − H_kᵀΘ̂p (measured generalized input minus the model's need), so a
resisting load that the model lacks gives a positive column.

Hypotheses (``Hypothesis.name`` equals the effect name the emulator's effects file uses):

=========================  ==============================================  =====================
name                       columns                                         magnitude reported
=========================  ==============================================  =====================
payload                    Θ̂_{m_ch}, Θ̂_{C_ch}, centre-of-mass offset       Δm [kg]; with free base
                                                                           parameters the offset's
                                                                           first moment only [kg m]
incline                    m_ch·g along world x, y in the chassis frame   angle [rad]
stribeck (wheels/steering) d_c·exp(−(v/v_s)²)·s(v), v_s profiled; s the   breakaway ratio − 1
                           direction of sliding, or of the motion ending a
                           stick
rolling_resistance         (m_ch g r / 4)·tanh(β̇_i/ε) per wheel           c_rr [-]
actuator_delay             H_kᵀB(u(t) − u(t − T_d)), T_d profiled           T_d [s]
torque_constant_error      −H_kᵀB e_j u_j for one drive j                  factor − 1 [-]
wheel_radius               (kinematic) predicted rolling angle; (torque)    r_nominal/r − 1 [-]
                           −(steering-joint terms) − 2·(Θ̂_{m_ch} m_ch +
                           Θ̂_{C_ch} C_ch): odometry's scale
backlash                   (kinematic) ½·tanh(u_i/0.05 N m); chassis        gap [rad, wheel side]
                           steps: the lead δβ_i = ½·tanh(u_i(t − t_c)/u_t),
                           t_c, u_t profiled, its rate (rolling) and
                           −H_kᵀY(q, δq̇, δq̈)p̂ of it (torque)
steering_compliance        (torque) scrub drag μN·|δ| of the toed rear    1/stiffness [rad/(N m)]
                           wheels, δ = T/k of the linkage torque T
                           through the held joints' stiction play d_c/2;
                           the rotation's drag: s_rot/k, 0 ≤ s_rot ≤ 1.5;
                           (torque, held steering) the odometry's error
                           from the rear toe rolling the encoders see:
                           c_odo (1 for a toe that explains it)
tire_slip                  (rolling) lateral slip of a rigid chassis whose  1/C_α [rad/N]
                           side forces need slip angles F/C_α
heavy_steering_units       exact point masses at the wheel centres          m_w [kg]
=========================  ==============================================  =====================
"""
from __future__ import annotations

import importlib
import pkgutil

from .base import Hypothesis, Magnitude, plausible
from .generic import generic


def _discover() -> tuple[Hypothesis, ...]:
    """The ``HYPOTHESES`` of every plug-in module of this package, in module-name order."""
    found: list[Hypothesis] = []
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda i: i.name):
        module = importlib.import_module(f"{__name__}.{info.name}")
        found += getattr(module, "HYPOTHESES", ())
    return tuple(found)


#: Every hypothesis the diagnosis tests: a plug-in module of this package that declares ``HYPOTHESES`` is
#: part of it by being there.
LIBRARY: tuple[Hypothesis, ...] = _discover()


__all__ = ["Hypothesis", "Magnitude", "LIBRARY", "generic", "plausible"]


def library(model_from_data: bool = False) -> tuple[Hypothesis, ...]:
    """The hypotheses to test: :data:`LIBRARY`, where the base parameters are free (``model_from_data``:
    a model identified on the diagnosed data) with each hypothesis replaced by its ``free_base`` form
    (only the coefficients no base parameter can take)."""
    if not model_from_data:
        return LIBRARY
    return tuple(h.free_base or h for h in LIBRARY)
