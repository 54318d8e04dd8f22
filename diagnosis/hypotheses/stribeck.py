"""Stribeck friction: a breakaway peak d_c·exp(−(v/v_s)²) in the wheel or the steering joints, v_s profiled."""
from __future__ import annotations

import numpy as np
from scipy import stats

from qomni.conventions import EPSILON as EPS_SIGN

from ..channels import ChannelData, held_off_sides, steering_offset
from .base import LIFTED_MODELLED, Hypothesis, RuleRows, _linear_magnitude, _project, _torque_only


#: rad/s, joint side: below this speed a joint is taken as sticking. Its friction then holds against the
#: motion that breaks it loose, so its direction is that motion's, which tanh(v/ε) of the filtered speed
#: (≈ 0 there) does not give: the stick-slip transients at every reversal are where a friction peak
#: shows most, and the filter spreads them into the moving rows next to the stuck ones.
STICK_VELOCITY = 0.01


def _friction_direction(v: np.ndarray) -> np.ndarray:
    """(N, m) direction friction acts in, within ±1: tanh(v/ε) where a joint slides, and where it sticks
    the sign of the motion that ends the stick (the motion before it if none follows)."""
    v = np.asarray(v, dtype=float)
    out = np.tanh(v / EPS_SIGN)
    rows = np.arange(len(v))
    for j in range(v.shape[1]):
        sliding = np.abs(v[:, j]) > STICK_VELOCITY
        if not sliding.any():
            continue
        slide_rows = rows[sliding]
        # the first sliding row after each stuck one, or the last sliding row when none follows
        after = np.minimum(np.searchsorted(slide_rows, rows[~sliding]), len(slide_rows) - 1)
        out[~sliding, j] = np.sign(v[slide_rows[after], j])
    return out


def _stribeck(v, v_s):
    return np.exp(-(v / v_s) ** 2) * _friction_direction(v)


STRIBECK_VELOCITIES = (0.02, 0.05, 0.1, 0.2, 0.4)  # rad/s, joint side


@_torque_only
def _stribeck_wheel_columns(ch: ChannelData, v_s):
    st = ch.context.st
    Q = np.zeros((len(st.time), 9))
    Q[:, 5:9] = ch.context.p[9] * _stribeck(st.qd_coulomb[:, 5:9], v_s)
    return _project(ch, Q, smooth=True)[:, None]


@_torque_only
def _stribeck_steering_columns(ch: ChannelData, v_s):
    ctx = ch.context
    peak = _stribeck(ctx.alpha_dot_encoder, v_s)
    Q = np.zeros((len(ctx.st.time), 9))
    Q[:, 3] = ctx.p[2] * peak[:, 0]
    Q[:, 4] = ctx.p[5] * peak[:, 1]
    return _project(ch, Q, smooth=True)[:, None]


def _stribeck_both_columns(ch: ChannelData, v_s):
    """(N, 2): the wheel joints' column and the steering joints' at one Stribeck velocity."""
    wheels, steering = _stribeck_wheel_columns(ch, v_s), _stribeck_steering_columns(ch, v_s)
    if wheels is None and steering is None:
        return None
    n = len(ch.y)
    return np.hstack([np.zeros((n, 1)) if c is None else c for c in (wheels, steering)])


#: One-sided z (5 %) the wheel joints' Stribeck level must reach in the steps without steering motion
#: (modes 2–4), beyond the reference run's level there, to be preferred over the steering joints' variant.
#: The level is fitted on all of those steps' rows: the placement only chooses between two variants
#: whose significance the steering steps' fit rows established.
WHEEL_FRICTION_Z = 1.645
#: One-sided z (5 %) the steering joints' coefficient of the both-joints fit must reach beyond the
#: reference run's level for friction in both joints to be named in a run without a lane change
#: (:func:`_in_both_joints`).
STEERING_BEYOND_WHEELS_Z = 1.645
#: One-sided z (5 %) the steering joints' Stribeck level in the lane change's steering channel must reach
#: beyond the reference run's level there, at the Stribeck velocity the steering variant's fit profiled on
#: the steering steps, for friction in both joints to be named. That velocity is chosen on other rows, so
#: the lane change is tested once, not over the grid.
LANE_CHANGE_STEERING_Z = float(stats.norm.isf(0.05))
#: The lifted breakaway test (:mod:`qomni.ident.breakaway`) finds a low-speed peak in the wheel joints
#: where its breakaway excess (breakaway / lifted d_cw − 1) is beyond 0 by a one-sided z of
#: LIFTED_BREAKAWAY_Z (10⁻³, the rules' level for a measurement that decides alone) and at least
#: LIFTED_BREAKAWAY_EXCESS: half the weakest peak of the realistic range (breakaway 1.2 × d_c). Without a
#: peak the test reads −0.3…2.1 % (σ 0.2–0.5 %), with gear play as well; the realistic range's weak end
#: reads 15–21 % (docs/diagnosis.md, "Stribeck: the lifted breakaway test").
LIFTED_BREAKAWAY_Z = float(stats.norm.isf(1e-3))
LIFTED_BREAKAWAY_EXCESS = 0.1


def tell_friction_joints_apart(candidates: list, unsteered_z, steered_z=None, unsteered_sigma=None,
                               held_off: str | None = None) -> None:
    """Decide between the two Stribeck variants where they differ.

    In mode 1 the steered wheels roll with the steering (β̇ = H₁α̇), so low-speed friction of the wheel
    joints and of the steering joints shape the steering steps alike, and the steering variant usually
    fits them a little better. Only steps in which the wheels turn without steering (modes 2–4) tell
    them apart: there the steering joints' variant has no column. ``unsteered_z(v_s)`` is the z of the
    wheel variant's level fitted on those steps alone beyond the reference run's level there
    (:func:`unsteered_wheel_level`). When the steering variant is significant and that z reaches
    ``WHEEL_FRICTION_Z``, the wheel variant is reported instead: the steering steps establish low-speed
    friction, the unsteered steps place it in the wheel joints. Below it the steering variant is, even
    where the wheel variant removes a little more held-out residual: the steps that could show wheel-joint
    friction do not. The same holds when only the wheel variant passes the test of the steering steps
    and the steering variant confirms on held-out data as well: the steering variant is then reported,
    with that test's significance. When it does not confirm, the wheel variant stays.

    Friction in both joints at once: where the unsteered steps place friction in the wheel joints
    (``z`` at the bar) and the lane change, whose steering turns while the wheels roll at speed, places
    friction in the steering joints as well (``steered_z(v_s)``: the steering variant's level in the lane
    change's steering channel beyond the reference run's, asked at the Stribeck velocity the steering
    variant's fit profiled on the steering steps), the both-joints variant is named instead
    (:func:`_in_both_joints`); or where the rotation holds the steering off the mode's angle
    (``held_off``, :func:`steering_held_off`). It is never named by its own test. ``steered_z`` None (or
    None at v_s): the run has no lane change, and the both-joints fit's steering coefficient decides.

    The bar for the unsteered steps is ``WHEEL_FRICTION_Z`` or, where it is lower, half the z the wheel
    variant's own level (fitted on the steering steps, beyond the reference's) would have there
    (``unsteered_sigma(v_s)``: σ of the level in the unsteered steps): the unsteered level is then
    closer to the wheel joints' prediction than to none, the maximum-likelihood choice between the two
    placements. A significance test of the unsteered level alone has little power where the wheel
    variant's level is low against its σ there: on quick campaigns (master seed 2611) a heavy platform's
    wheel-joint friction read z = 1.4 against a predicted 1.7 (placed in the steering joints by the
    test alone), a wheel-joint case 2.7 against 3.7, a steering-joint case 0.1 against 2.9."""
    wheels, steering, both = _variants(candidates)
    if wheels is None or steering is None or not (steering.significant or wheels.significant):
        return
    z = unsteered_z(wheels.fit.nonlinear)
    if z is None:
        return
    predicted = _predicted_unsteered_z(wheels, None if unsteered_sigma is None
                                       else unsteered_sigma(wheels.fit.nonlinear))
    bar = _unsteered_bar(predicted)
    z_lc = None if steered_z is None else steered_z(steering.fit.nonlinear)
    _wheels_or_steering(wheels, steering, z, bar)
    if both is not None and z >= bar and (wheels.significant or steering.significant):
        _in_both_joints(both, wheels, steering, z, z_lc, held_off=held_off)
    evidence = _placement_evidence(z, bar, predicted, z_lc, steering.fit.nonlinear, held_off)
    for c in (wheels, steering, both):
        if c is not None:
            c.notes.append(evidence)


def _variants(candidates: list) -> tuple:
    """The (wheels, steering, both) Stribeck candidates (None where absent); the both-joints variant
    made not significant: the placement rules alone name it."""
    by_variant = {c.hypothesis.variant: c for c in candidates if c.hypothesis.name == "stribeck"}
    both = by_variant.get("joints=both")
    if both is not None:
        both.significant = False
    return by_variant.get("joints=wheels"), by_variant.get("joints=steering"), both


def lifted_peak(breakaway: tuple[float, float] | None) -> bool:
    """Whether the lifted breakaway test's (excess, σ) shows a low-speed peak in the wheel joints:
    excess ≥ LIFTED_BREAKAWAY_EXCESS and excess/σ ≥ LIFTED_BREAKAWAY_Z. None (no test): False."""
    if breakaway is None:
        return False
    excess, std = breakaway
    return excess >= LIFTED_BREAKAWAY_EXCESS and excess / std >= LIFTED_BREAKAWAY_Z


def place_by_lifted_breakaway(candidates: list, breakaway: tuple[float, float], steered_z=None,
                              held_off: str | None = None) -> None:
    """Decide between the Stribeck variants by the lifted breakaway test: the wheel joints' breakaway
    excess measured on the lifted vehicle (``breakaway``: (excess, σ), :mod:`qomni.ident.breakaway`),
    where only the wheel joints' friction resists a drive's torque.

    The ground's data establish low-speed friction (one variant significant); the lifted test places it.
    With a peak in the wheel joints (excess ≥ LIFTED_BREAKAWAY_EXCESS and z ≥ LIFTED_BREAKAWAY_Z) the wheel
    variant is named, with the steering variant's significance where only that one passed; and the
    both-joints variant instead where the lane change places friction in the steering joints as well
    (``steered_z``, as in :func:`tell_friction_joints_apart`) or the rotation holds the steering off the
    mode's angle (``held_off``, :func:`steering_held_off`). Without one the wheel variant is withdrawn,
    and the steering variant named where it is physical, confirms on held-out data and is there, with the
    wheel variant's significance where only that one passed. The steps without steering motion are not
    asked: a wheel-joint level there competes with the Coulomb-like levels each step keeps where friction
    differs from the model's (:func:`unsteered_wheel_level`), while the lifted wheel has nothing else."""
    from ..evaluation import MIN_SHRINK   # the fitting machinery imports this package: import at use
    from ..fit import present

    wheels, steering, both = _variants(candidates)
    if wheels is None or steering is None or not (steering.significant or wheels.significant):
        return
    excess, std = breakaway
    z = excess / std
    peak = lifted_peak(breakaway)
    evidence = (f"placement: the lifted wheels break away at {1 + excess:.3f} × their Coulomb friction "
                f"(excess {excess:.3f} ± {std:.3f}, z = {z:.1f}; a peak needs ≥ {LIFTED_BREAKAWAY_EXCESS:g} "
                f"and z ≥ {LIFTED_BREAKAWAY_Z:.2f})")
    if peak:
        if steering.significant:
            steering.significant = False
            steering.notes.append("the lifted wheels break away above their Coulomb friction: the wheel "
                                  "joints' variant is named")
            if not wheels.significant:
                wheels.significant = wheels.physical and wheels.evaluation.confirms(MIN_SHRINK) \
                    and present(wheels)
                wheels.notes.append(f"significance from the steering variant's test of the steering steps "
                                    f"(p = {steering.p_value:.1e})")
        z_lc = None if steered_z is None else steered_z(steering.fit.nonlinear)
        if both is not None and wheels.significant:
            _in_both_joints(both, wheels, steering, z, z_lc,
                            f"the lifted wheels break away {excess:.3f} above their Coulomb friction (z = {z:.1f})",
                            held_off)
        evidence += _steering_evidence(z_lc, steering.fit.nonlinear, held_off)
    else:
        if wheels.significant:
            wheels.significant = False
            wheels.notes.append("not named: the lifted wheels break away at their Coulomb friction")
            if not steering.significant and steering.physical and steering.evaluation.confirms(MIN_SHRINK) \
                    and present(steering):
                steering.significant = True
                steering.notes.append(f"named in the steering joints: the lifted wheels have no peak; "
                                      f"significance from the wheel variant's test of the steering steps "
                                      f"(p = {wheels.p_value:.1e})")
    for c in (wheels, steering, both):
        if c is not None:
            c.notes.append(evidence)


def _predicted_unsteered_z(wheels, sigma: float | None) -> float | None:
    """The z the wheel variant's level fitted on the steering steps (beyond the reference's) would have in
    the steps without steering motion, whose level has σ ``sigma`` there; None without that σ."""
    if sigma is None or not sigma > 0:
        return None
    theta = float(np.asarray(wheels.fit.theta)[0])
    theta0 = 0.0 if getattr(wheels.fit, "theta0", None) is None else float(np.asarray(wheels.fit.theta0)[0])
    return (theta - theta0) / sigma


def _placement_evidence(z: float, bar: float, predicted: float | None, z_lane_change: float | None,
                        v_s_steering, held_off: str | None = None) -> str:
    """The note that states what the placement read (every Stribeck variant carries it)."""
    text = f"placement: the wheel joints' level in the steps without steering motion z = {z:.2f} (bar {bar:.2f}"
    text += ")" if predicted is None else f", the wheel variant predicts {predicted:.2f})"
    return text + _steering_evidence(z_lane_change, v_s_steering, held_off)


def _steering_evidence(z_lane_change: float | None, v_s_steering, held_off: str | None) -> str:
    """The placement note's part on the steering joints: the lane change's level (where it was asked) and
    the rotation's steering offset (where it reads, :func:`steering_held_off`), each "; "-led; "" without."""
    text = "" if z_lane_change is None else (
        f"; the steering joints' level in the lane change z = {z_lane_change:.2f} at "
        f"{v_s_steering:g} rad/s (bar {LANE_CHANGE_STEERING_Z:.3f})")
    return text if held_off is None else f"{text}; {held_off}"


def _unsteered_bar(predicted: float | None) -> float:
    """The z the wheel variant's level in the unsteered steps must reach: WHEEL_FRICTION_Z, or half the z
    its level fitted on the steering steps (beyond the reference's) would have there (``predicted``, from
    :func:`_predicted_unsteered_z`), where that is lower (:func:`tell_friction_joints_apart`)."""
    return min(WHEEL_FRICTION_Z, 0.5 * predicted) if predicted is not None and predicted > 0 \
        else WHEEL_FRICTION_Z


def _in_both_joints(both, wheels, steering, z: float, z_lane_change: float | None = None,
                    wheel_evidence: str = "", held_off: str | None = None) -> None:
    """Name the both-joints variant in place of the single-joint one the placement chose, when the
    steering joints' level in the lane change (``z_lane_change``, at the Stribeck velocity of the steering
    variant's fit) exceeds the reference run's level there by LANE_CHANGE_STEERING_Z: the wheel joints are
    placed by the steps without steering motion (``z``), the steering joints by the one step whose steering
    turns while the wheels roll at speed. The steering steps cannot place it: there the two columns are
    nearly collinear, and a wheel-joint peak shows stronger than its column (the slowly rolling steered
    wheels stick and slip), so the both-joints fit hands the excess to the steering joints. Without a lane
    change (``z_lane_change`` None) the both-joints fit's steering coefficient beyond the reference run's
    decides. ``wheel_evidence``: what placed the wheel joints' share, for the note (default: the steps
    without steering motion at ``z``). ``held_off``: where the rotation holds the steering off the mode's
    angle and the reference run does not (:func:`steering_held_off`), what it read: static friction in
    the steering joints, which places their share where the level test does not reach the bar (a peak
    narrower than the lane change's reversals resolve)."""
    from ..fit import coefficient_z, present  # the fitting machinery imports this package: import at use

    if z_lane_change is None:
        # the steering coefficient (the fit's last) beyond the reference run's: what the steering steps
        # need beyond the wheel joints' level, which the steps without steering motion hold in the same fit
        z_s, bar, where = coefficient_z(both.fit, -1), STEERING_BEYOND_WHEELS_Z, "the steering steps"
    else:
        z_s, bar, where = z_lane_change, LANE_CHANGE_STEERING_Z, "the lane change"
    if z_s < bar and held_off is None:
        both.notes.append(f"no steering-joint friction beyond the reference run's in {where} "
                          f"(z = {z_s:.1f} < {bar:.2f}) nor a steering held off the rotation's angles: "
                          f"not named")
        return
    if not both.physical or not present(both):
        both.notes.append("the both-joints fit is not physical or its level not there: not named")
        return
    chosen = wheels if wheels.significant else steering
    both.significant = True
    wheel_evidence = wheel_evidence or (f"the wheel joints' level in the steps without steering motion exceeds "
                                        f"the reference run's by z = {z:.1f}")
    steering_evidence = (f"the steering joints' level in {where} exceeds the reference run's by z = {z_s:.1f}"
                         if z_s >= bar else held_off)
    both.notes.append(f"{wheel_evidence}, and {steering_evidence}; steering joints' breakaway/Coulomb − 1 = "
                      f"{both.fit.theta[-1]:.3g}; significance from the {chosen.hypothesis.variant} variant's "
                      f"test (p = {chosen.p_value:.1e})")
    for single in (wheels, steering):
        if single.significant:
            single.significant = False
            single.notes.append("the both-joints variant is preferred: friction in the wheel and the "
                                + (f"steering joints (z = {z:.1f} and {z_s:.1f})" if z_s >= bar
                                   else f"steering joints (z = {z:.1f}; {held_off})"))


def _wheels_or_steering(wheels, steering, z: float, bar: float = WHEEL_FRICTION_Z) -> None:
    """The placement between the two single-joint variants (:func:`tell_friction_joints_apart`)."""
    from ..evaluation import MIN_SHRINK   # the fitting machinery imports this package: import at use
    from ..fit import present

    if z < bar:
        if not wheels.significant:
            return
        if not steering.significant:
            if not (steering.physical and steering.evaluation.confirms(MIN_SHRINK) and present(steering)):
                return
            steering.significant = True
            steering.notes.append(f"preferred over the wheel joints, whose level in the steps without "
                                  f"steering motion is not beyond the reference run's (z = {z:.1f}); "
                                  f"significance from the wheel variant's test of the steering steps "
                                  f"(p = {wheels.p_value:.1e})")
        wheels.significant = False
        wheels.notes.append(f"the steering joints' variant is preferred: this one's level in the steps "
                            f"without steering motion is not beyond the reference run's (z = {z:.1f} "
                            f"< {bar:.4g})")
        return
    if not steering.significant:
        return
    steering.significant = False
    steering.notes.append(f"the wheel joints' variant also explains the steps without steering motion "
                          f"(z = {z:.1f}); this one has no column there")
    wheels.significant = wheels.physical and wheels.evaluation.confirms(MIN_SHRINK) and present(wheels)
    wheels.notes.append(f"preferred over the steering joints: its level in the steps without steering "
                        f"motion exceeds the reference run's by z = {z:.1f}; significance from the "
                        f"steering variant's test of the steering steps (p = {steering.p_value:.1e})")


def unsteered_wheel_level(all_rows, ref_problem, model, lag: int, cache: dict):
    """``v_s ↦ (z, σ)`` of the wheel joints' Stribeck level in the steps without steering motion: z beyond
    the reference run's level in the same steps (beyond 0 without a reference run), σ of the level; None
    where the variant has no column there. One fit per v_s, kept for a second call.

    The level is fitted beside a free Coulomb level per step, every channel weighted by what that fit
    leaves of it (:func:`qomni.diagnosis.fit.level_beside_step_levels`). Where low-speed friction
    differs from the model's, the steps keep Coulomb-like levels ±c·tanh(ṡ/ε) of their own that no base
    parameter holds: draw 8795's straight step, paired with the twin, holds −5 and −12 N on two
    steering-joint cases and +16 N on a both-joint case of breakaway ratio 2, nearly all of its RMS,
    and the left arc of the same cases +0.5, +17 and −18 N, so no one shift of d_cw holds them. The
    question here is the low-speed peak, which such a level does not hold; fitted without it, the
    level counted as noise in the channel weights and hid that case's peak (z = 1.4; 9.6 with the
    levels taken out).

    ``all_rows``: the diagnosed run with every row a fit row. Fitted on the alternate windows alone, the
    low wheel-joint cases of full campaigns (breakaway 1.5× d_c) reached z = 1.0–1.5 and were placed in
    the steering joints; on all rows 1.2–2.0 (ideal runs ≤ 0.05, steering-joint friction ≤ 0.2)."""
    from .. import fit as fitting           # the fitting machinery imports this package: import at use
    from ..problem import restrict

    def unsteered(ch):
        return ch.context.k != 1

    rows = restrict(all_rows, unsteered)
    reference = None if ref_problem is None else restrict(ref_problem, unsteered)
    fitted: dict = {}

    def level(v_s):
        if v_s not in fitted:
            fitted[v_s] = fitting.level_beside_step_levels(rows, reference, model, STRIBECK_WHEELS, v_s, lag,
                                                           cache)
        return fitted[v_s]
    return level


def _z_beyond_reference(rows, reference, model, h, v_s, lag: int, cache: dict) -> float | None:
    """z of ``h``'s level at ``v_s`` on ``rows`` beyond its level on the reference run's ``reference``
    (fitted at this v_s only: reference_levels would fit the whole grid), beyond 0 without one."""
    from .. import fit as fitting           # the fitting machinery imports this package: import at use

    ref = None if reference is None else fitting.solve(reference, model, h, v_s, lag, cache)
    return fitting.level_z(rows, model, h, v_s, lag, cache, None if ref is None else ref.theta)


def lane_change_steering_z(steering_rows, steering_reference, model, lag: int, cache: dict):
    """``v_s ↦ z`` of the steering joints' Stribeck level in the lane change's steering channel beyond
    the reference run's level there (beyond 0 without a reference run); None without that channel.

    In the lane change (mode 2) the steering turns and reverses while the chassis drives: wherever the
    steering slows below 0.05 rad/s, away from the step's first and last second, the wheels roll at
    0.5 rad/s or more (an ideal full campaign), 2.5× the largest Stribeck velocity of the realistic range,
    so a low-speed peak there is the steering joints'.
    On the full campaigns of draw 6151 its largest z over the grid stayed within −0.4…0.9 in all 6
    wheel-joint cases and reached 3.0–4.7 in all 6 steering- and both-joint cases whose peak is wider
    than 0.025 rad/s; of the 6 narrower ones (0.011–0.021 rad/s), which the lane change's reversals cross
    within a few samples, it reached 2.8 and 3.6 in 2. At the steering variant's own Stribeck velocity
    (the one the placement asks), over the recorded draws 5519, 4177, 2762 and 2611: 13 wheel-joint cases
    −2.2…0.1, 10 steering-joint cases −0.3…4.7, 12 both-joint cases 0.1…4.2."""
    if steering_rows is None:
        return None
    return lambda v_s: _z_beyond_reference(steering_rows, steering_reference, model, STRIBECK_STEERING,
                                           v_s, lag, cache)


def steering_held_off(all_rows, reference=None) -> str | None:
    """What shows static friction in the steering joints beyond the model's: a side whose steering the
    diagnosed run's rotation holds ``channels.MISALIGNMENT_LSB`` sensor LSBs or more off the mode's angle
    (:func:`qomni.diagnosis.channels.held_off_sides`), where the reference run's rotation holds both sides
    on the mode's angle. None where no side is, where the run has no rotation, or where the reference run
    holds a side off itself: its controller then does not hold even the model's friction on target (a
    steering bandwidth lowered for an actuator delay: a 20 ms delay's twin, whose friction breaks away
    at its Coulomb level, held one side 19 LSB off), so an offset says nothing of the friction.

    Mode 4 holds every steering angle fixed while the wheels roll fast, so the steering drives only have
    to hold a position against the scrub; a drive whose joint breaks away above its Coulomb friction
    stops short of its target where the model's friction would not. The bar is the misalignment
    columns' (2.0 LSB, 0.77 mrad: the controller's integral deadband plus the reading's rounding): on full
    campaigns 54 vehicles without steering-joint Stribeck friction (wheel-joint Stribeck friction at both
    ends of its range among them) and every twin at the default steering bandwidth held both sides within
    1.4 LSB; 14 of 21 with steering-joint Stribeck friction held a side 2.3–66 LSB off (docs/diagnosis.md,
    "The steering held off"). A static measurement, like the lifted wheels' breakaway, it places friction
    in the steering joints where the lane change does not: peaks narrower than its reversals
    (0.016–0.031 rad/s) read there z = −1.3 to −3.4 while the rotation holds both sides 3.1–11 LSB off.

    Args:
        all_rows: the diagnosed run's problem (:mod:`qomni.diagnosis.problem`); its rotation channels'
            ``context`` carries the step's signals.
        reference: the reference run's problem, or None (no reference: the diagnosed run alone decides).
    Returns:
        The note's text (each held-off side's offset in LSB, signed, and the reference run's there), or None.
    """
    def rotation(problem):
        return None if problem is None else next(
            (ch.context for ch in problem.channels if ch.context.rolling is not None), None)

    ctx = rotation(all_rows)
    ref = rotation(reference)
    if ctx is None or (ref is not None and held_off_sides(ref)):
        return None
    sides = held_off_sides(ctx)
    if not sides:
        return None
    lsb = ctx.sheet.drive.steering_lsb
    offset = steering_offset(ctx) / lsb
    text = "the rotation holds the steering " + ", ".join(
        f"{('left', 'right')[side]} {offset[side]:+.1f} LSB" for side in sides) + " off the mode's angle"
    if ref is not None:
        ref_offset = steering_offset(ref) / lsb
        text += " (the reference run " + ", ".join(f"{ref_offset[side]:+.1f}" for side in sides) + ")"
    return text


def resolve_joints(candidates: list, rows: RuleRows) -> None:
    """The Stribeck variants' rule (``Hypothesis.resolve``): where the run has the lifted breakaway test,
    :func:`place_by_lifted_breakaway`; otherwise :func:`tell_friction_joints_apart` with the wheel
    variant's level in the steps without steering motion (:func:`unsteered_wheel_level`). Both take the
    steering variant's level in the lane change (:func:`lane_change_steering_z`) and the rotation's
    steering offset (:func:`steering_held_off`) for the steering joints' share."""
    steered = lane_change_steering_z(rows.steering, rows.steering_reference, rows.model, rows.lag,
                                     rows.cache)
    held_off = steering_held_off(rows.all_rows, rows.reference)
    if rows.lifted_breakaway is not None:
        place_by_lifted_breakaway(candidates, rows.lifted_breakaway, steered, held_off)
        return
    level = unsteered_wheel_level(rows.all_rows, rows.reference, rows.model, rows.lag, rows.cache)
    tell_friction_joints_apart(candidates,
                               lambda v_s: None if level(v_s) is None else level(v_s)[0],
                               steered,
                               lambda v_s: None if level(v_s) is None else level(v_s)[1],
                               held_off)


STRIBECK_WHEELS = Hypothesis(
    "stribeck", "joints=wheels", ("breakaway_excess",), _stribeck_wheel_columns, STRIBECK_VELOCITIES,
    magnitude=_linear_magnitude(0, "-", "breakaway/Coulomb − 1 (wheel joints)"),
    physical=lambda t: t[0] > 0, nonlinear_unit="rad/s (Stribeck velocity)", resolve=resolve_joints,
    lifted=LIFTED_MODELLED)
STRIBECK_STEERING = Hypothesis(
    "stribeck", "joints=steering", ("breakaway_excess",), _stribeck_steering_columns,
    STRIBECK_VELOCITIES, magnitude=_linear_magnitude(0, "-", "breakaway/Coulomb − 1 (steering joints)"),
    physical=lambda t: t[0] > 0, nonlinear_unit="rad/s (Stribeck velocity)", resolve=resolve_joints,
    lifted=LIFTED_MODELLED)

STRIBECK_BOTH = Hypothesis(
    "stribeck", "joints=both", ("breakaway_excess_wheels", "breakaway_excess_steering"),
    _stribeck_both_columns, STRIBECK_VELOCITIES,
    magnitude=_linear_magnitude(0, "-", "breakaway/Coulomb − 1 (wheel joints; the steering joints' in the notes)"),
    physical=lambda t: t[0] > 0 and t[1] > 0, nonlinear_unit="rad/s (Stribeck velocity)",
    resolve=resolve_joints, lifted=LIFTED_MODELLED)

#: The hypotheses this module adds to the library (:data:`qomni.diagnosis.hypotheses.LIBRARY`).
HYPOTHESES = (STRIBECK_WHEELS, STRIBECK_STEERING, STRIBECK_BOTH)
