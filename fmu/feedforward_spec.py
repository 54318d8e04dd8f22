"""The feed-forward FMU's spec: the law (21), motor torques from q, s_dot_k, s_ddot_k and the identified p.

Variables (value references in this order, time = 0; FMI 2 indices = value reference + 1):

* ``time`` (independent, s);
* tunable parameters ``C_l, d_vl, d_cl, C_r, d_vr, d_cr, m_ch, C_ch, d_vw, d_cw, B_w`` (p of (18),
  start = identified values), ``l, b, a, r`` (m), ``i_G`` (-), ``eps`` (rad/s) and the Boolean
  ``use_alpha_v_input``;
* inputs ``k`` (Integer/Int32 1..4, motion mode), ``q.x_ch, q.y_ch, q.gamma_ch, q.alpha_l, q.alpha_r,
  q.beta_fl, q.beta_rl, q.beta_fr, q.beta_rr`` (q; only alpha_l, alpha_r are used by (21)),
  ``s_dot[1], s_dot[2], s_ddot[1], s_ddot[2]`` (s_dot_k, s_ddot_k of (10)-(13); entries beyond n_k
  ignored), ``alpha_v`` (rad; mode 2 only and only if ``use_alpha_v_input``: then
  alpha = f_ICR(alpha_v), otherwise alpha_v is computed from q.alpha_l, q.alpha_r); q.alpha_l, q.alpha_r
  declare the stops +-steering_limit and alpha_v +-arctan(l/b) as min/max (:func:`steering_limits`), and a
  value beyond is refused when set;
* outputs ``motor_torque.fl, .rl, .fr, .rr``: u of (21), N m, motor side of the gear.

The outputs are a direct-feedthrough algebraic function of the inputs (no internal states), so any
communication step size > 0 is accepted (canHandleVariableCommunicationStepSize). Invalid inputs (k not
in 1..4, alpha far from mode 2 in mode 2, ...) make reading the outputs fail with fmi2Error/fmi3Error
and a log message.
"""
from __future__ import annotations

import math

from qomni.conventions import EPSILON, PARAMETER_NAMES, WHEELS
from qomni.ident.symbolic import COORDINATE_NAMES

from . import codegen
from .spec import ModelSpec
from .variables import Variable, number_variables

DEFAULT_EPS = EPSILON
"""rad/s; default tanh smoothing (the paper's ε, :data:`qomni.conventions.EPSILON`)."""

_PARAMETER_INFO = {  # name: (unit, description)
    "C_l": ("kg.m2", "steering inertia, left side (front + rear)"),
    "d_vl": ("N.m.s/rad", "viscous steering friction, left side"),
    "d_cl": ("N.m", "Coulomb steering friction, left side"),
    "C_r": ("kg.m2", "steering inertia, right side (front + rear)"),
    "d_vr": ("N.m.s/rad", "viscous steering friction, right side"),
    "d_cr": ("N.m", "Coulomb steering friction, right side"),
    "m_ch": ("kg", "total vehicle mass"),
    "C_ch": ("kg.m2", "chassis yaw inertia"),
    "d_vw": ("N.m.s/rad", "viscous friction per wheel, wheel side of the gear"),
    "d_cw": ("N.m", "Coulomb friction per wheel, wheel side of the gear"),
    "B_w": ("kg.m2", "motor + gear + wheel inertia about the wheel axle (fixed p_2 of (24))"),
}
_COORDINATE_INFO = {
    "x_ch": ("m", "chassis x position (not used by (21))"),
    "y_ch": ("m", "chassis y position (not used by (21))"),
    "gamma_ch": ("rad", "chassis yaw angle (not used by (21))"),
    "alpha_l": ("rad", "desired left steering angle alpha_l = phi_fl = -phi_rl"),
    "alpha_r": ("rad", "desired right steering angle alpha_r = phi_fr = -phi_rr"),
}


def feedforward_variables(p: dict[str, float], geometry, i_G: float, eps: float = DEFAULT_EPS,
                          std: dict[str, float] | None = None) -> list[Variable]:
    """The variables of the feed-forward FMU (order = value references, see the module docstring).

    Args:
        p: {name: value} of the 11 parameters of (18), SI.
        geometry: object with ``l, b, a, r`` (m), e.g. :class:`ident.datasheet.Geometry`.
        i_G: gear ratio (> 0); eps: tanh smoothing, rad/s (> 0).
        std: optional {name: standard deviation} put into the parameter descriptions.
    Returns:
        list of :class:`Variable` with ``vr`` and ``index`` assigned.
    Raises:
        KeyError: a parameter is missing from ``p``. ValueError: non-finite value, i_G or eps <= 0.
    """
    std = std or {}
    out: list[Variable] = [Variable("time", "Float64", "independent", "continuous", "simulation time",
                                    unit="s")]
    for j, name in enumerate(PARAMETER_NAMES):
        unit, text = _PARAMETER_INFO[name]
        value = float(p[name])
        note = f"identified {value:.6g}" + (f" +- {std[name]:.2g}" if name in std else "")
        out.append(Variable(name, "Float64", "parameter", "tunable", f"{text}, p[{j + 1}] of (18); {note}",
                            start=value, unit=unit, group="P" if j == 0 else None))
    for j, (name, text) in enumerate((("l", "longitudinal distance between the steering axes"),
                                      ("b", "lateral distance between the steering axes"),
                                      ("a", "lateral offset of the wheel centre from its steering axis"),
                                      ("r", "wheel radius"))):
        out.append(Variable(name, "Float64", "parameter", "tunable", text, start=float(getattr(geometry, name)),
                            unit="m", group="GEOMETRY" if j == 0 else None))
    out.append(Variable("i_G", "Float64", "parameter", "tunable",
                        "planetary gear ratio, wheel torque = i_G * motor torque", start=float(i_G), group="I_G"))
    out.append(Variable("eps", "Float64", "parameter", "tunable",
                        "tanh smoothing of Coulomb friction, d_c tanh(v/eps) (16)", start=float(eps),
                        unit="rad/s", group="EPS"))
    out.append(Variable("use_alpha_v_input", "Boolean", "parameter", "tunable",
                        "mode 2: take alpha_v from input alpha_v and alpha = f_ICR(alpha_v) (8); "
                        "false: alpha_v from q.alpha_l, q.alpha_r", start=False, group="USE_ALPHA_V_INPUT"))
    out.append(Variable("k", "Int32", "input", "discrete",
                        "motion mode (9): 1 wheel alignment, 2 steered longitudinal, 3 lateral, 4 rotation",
                        start=1, min=1, max=4, group="K"))
    for j, name in enumerate(COORDINATE_NAMES):
        unit, text = _COORDINATE_INFO.get(name, ("rad", f"wheel rolling angle {name} (not used by (21))"))
        out.append(Variable("q." + name, "Float64", "input", "continuous", f"q[{j + 1}]: {text}", start=0.0,
                            unit=unit, group="Q" if j == 0 else None))
    for prefix, what, unit_text in (("s_dot", "generalized velocity s_dot_k (10)-(13)", "rad/s or m/s"),
                                    ("s_ddot", "generalized acceleration s_ddot_k (20)", "rad/s2 or m/s2")):
        for j in (1, 2):
            meaning = {1: "k=1: alpha_l, k=2: alpha_v, k=3: y_ch, k=4: gamma_ch",
                       2: "k=1: alpha_r, k=2: x_ch, ignored for k=3, 4"}[j]
            out.append(Variable(f"{prefix}[{j}]", "Float64", "input", "continuous",
                                f"{what}, entry {j} ({meaning}), {unit_text}", start=0.0,
                                group=prefix.upper() if j == 1 else None))
    out.append(Variable("alpha_v", "Float64", "input", "continuous",
                        "virtual steering angle of mode 2 (used only if use_alpha_v_input)", start=0.0,
                        unit="rad", group="ALPHA_V"))
    for j, w in enumerate(WHEELS):
        out.append(Variable(f"motor_torque.{w}", "Float64", "output", "continuous",
                            f"feed-forward motor torque (21), wheel {w}, motor side of the gear",
                            unit="N.m", group="MOTOR_TORQUE" if j == 0 else None))
    if not i_G > 0:
        raise ValueError(f"i_G must be > 0, got {i_G!r}")
    if not eps > 0:
        raise ValueError(f"eps must be > 0 rad/s, got {eps!r}")
    return number_variables(out)


FEEDFORWARD_DEPENDENCIES = ("k", "q.alpha_l", "q.alpha_r", "s_dot[1]", "s_dot[2]", "s_ddot[1]", "s_ddot[2]",
                            "alpha_v")
"""Inputs every output of the feed-forward FMU depends on directly (ModelStructure)."""


def steering_limits(datasheet) -> dict[str, tuple[float, float]]:
    """The steering inputs' range: q.alpha_l, q.alpha_r within the mechanical stops +-steering_limit of the
    data sheet, alpha_v within +-arctan(l/b), where mode 2's inner wheel reaches its stop (rad)."""
    g = datasheet.geometry
    limit, av_max = float(g.steering_limit), math.atan2(float(g.l), float(g.b))
    return {"q.alpha_l": (-limit, limit), "q.alpha_r": (-limit, limit), "alpha_v": (-av_max, av_max)}


FEEDFORWARD = ModelSpec(
    kind="feedforward", default_identifier="qomni_feedforward", model_dir="feedforward",
    model_sources=("feedforward.c", "feedforward.h", "model.c"), generate=codegen.generate_c,
    variables=feedforward_variables, dependencies=FEEDFORWARD_DEPENDENCIES, config_prefix="FF", n_states=0,
    description=("Feed-forward control (21) of the quasi-omnidirectional platform '{name}': motor torques "
                 "from q, s_dot_k, s_ddot_k and the identified p"),
    summary="feed-forward law (21)", input_limits=steering_limits)
