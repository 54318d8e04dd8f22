"""Fitting hypotheses as nested extensions of the identified model, with significance, confidence
intervals, an identifiability check and held-out shrinkage.

Estimation problem for hypothesis e (all channels stacked, rows weighted per channel)::

    r_c = Θ̂₁,c δp + o_c + Φ_e,c θ_e + noise          (torque channel c: Θ̂₁ of (22); kinematic, rolling: offsets o_c)
    δp ~ N(0, Σ_prior)                                (the base parameters may move within their
                                                        uncertainty, nothing more)

With a model identified on the same rows there is no prior (the base parameters are free), except for
those measured independently (``Problem.measured``: the wheels' friction on the lifted vehicle),
δp_k ~ N(p_k,measured − p̂_k, (PRIOR_STD_FACTOR·σ_k,measured)²).

r_c is what the given model leaves in channel c. Row weights are 1/(σ_c·√L): σ_c the channel's residual
RMS under the base fit and L the rows over which the ω_g-filtered residuals stay correlated (so the data
count as n/L independent rows against the prior). The base fit is the same problem without Φ_e.

Significance is an F test of the weighted RSS reduction with n/L effective rows (profiled non-linear
parameters count as one more degree of freedom); magnitudes' 95 % intervals come from the covariance
of θ_e. Held-out data are never used for fitting: the rows of alternate time windows (or a second run),
on which the shrinkage 1 − RMS(after)/RMS(before) is measured per channel, with a window-bootstrap
interval. They confirm an effect when it shrinks its affected channel by at least MIN_SHRINK and the
weighted held-out residual over all channels does not grow (``Evaluation.confirms``).
"""
from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import stats
from scipy.linalg import solve_triangular

from qomni.conventions import EPSILON, P1_NAMES
from qomni.ident.result import IdentificationResult

from .channels import ChannelData
from .hypotheses.base import Hypothesis, Magnitude, columns_on, interval_95, plausible
from .evaluation import MIN_SHRINK, Evaluation, added_to_identified, evaluate, predicted_residual
from .problem import Fit, Problem, cached_columns, swapped

#: Significance level of the F test (first effect; further effects in forward selection: alpha_more).
#: The F test with n/L effective rows is conservative; the held-out shrinkage is the second gate.
ALPHA = 1e-2


def alpha_more(tested: int) -> float:
    """Significance level of a further effect in forward selection: ALPHA over the ``tested`` hypotheses
    re-tested in that round (Bonferroni). The first round's winner is ranked by held-out removal among
    the effects that pass ALPHA; a further one is picked from what is left once it is in the model,
    where the accepted effect's own misfit gives every remaining hypothesis a chance to fit something,
    so the family of tests is held at ALPHA as a whole."""
    return ALPHA / max(int(tested), 1)


#: Prior on the base parameters: σ = PRIOR_STD_FACTOR·σ_model. On ideal runs of other seeds the base fit
#: moves them by at most 1.1 of that. A wider prior lets a base parameter absorb an effect collinear with
#: it where the campaign shows it (heavy steering units: C_ch in the rotation).
PRIOR_STD_FACTOR = 3.0
#: Effect columns explained to more than this R² by the base columns are not separable from them.
COLLINEAR_R2 = 0.98
#: Whether held-out comparisons on alternate windows are cross-fitted: each hypothesis fitted a second
#: time on the held-out windows and evaluated on the fitted ones, so every window is held out once.
CROSS_FIT = True


def _shift(h: Hypothesis | None, nonlinear, theta0, ch: ChannelData, cache: dict | None) -> np.ndarray | None:
    """Φ_e θ₀ of one channel (the reference's level of the hypothesis), or None."""
    if h is None or theta0 is None:
        return None
    cols = cached_columns(h, nonlinear, ch, cache)
    return None if cols is None else cols @ theta0


def solve(problem: Problem, model: IdentificationResult, h: Hypothesis | None, nonlinear, lag: int,
          cache: dict | None = None, theta0: np.ndarray | None = None, held: int = 0) -> Fit | None:
    """Least squares of the stacked weighted rows plus the prior rows. None if the hypothesis has no
    column anywhere or its columns vanish.

    ``theta0``: the hypothesis' level in the reference run, taken as part of the base (θ = θ₀ + δθ).
    ``held``: the last ``held`` coefficients are kept at θ₀ instead (all of them: the base fit such a
    hypothesis is tested against; the new one's only: the base of an effect added to accepted ones,
    which stay free).

    The base and offset columns are the same for every hypothesis fitted on ``problem``: their block is
    factored once (QR, kept in ``cache``) and each hypothesis' columns are fitted to what that block
    leaves of the rows (Frisch–Waugh–Lovell), which gives the same solution, RSS and covariance of θ as
    the whole system. Where either part is rank-deficient the whole system is solved instead.

    Raises:
        ValueError: ``held`` without ``theta0``."""
    if held and theta0 is None:
        raise ValueError("coefficients held at θ₀ need θ₀")
    q = len(h.parameters) - held if h is not None else 0
    block = _base_block(problem, model, cache)
    n_base, n_cols = len(P1_NAMES), block.width + q
    blocks_E, blocks_b = [], []
    any_effect = False
    for i in block.used:
        ch, rows, w = problem.channels[i], problem.fit_rows[i], problem.weights[i]
        if q:
            E = np.zeros((int(rows.sum()), q))
            cols = cached_columns(h, nonlinear, ch, cache)
            if cols is not None:
                E[:] = cols[rows][:, :q]
                any_effect = any_effect or bool(np.any(cols[rows] != 0))
            blocks_E.append(E * w)
        target = ch.residual[rows]
        shift = _shift(h, nonlinear, theta0, ch, cache)
        if shift is not None:
            target = target - shift[rows]
        blocks_b.append(target * w)
    if q and not any_effect:
        return None
    b = np.concatenate(blocks_b + [block.prior_rhs])
    E = np.vstack(blocks_E + [np.zeros((len(block.prior_rhs), q))]) if q else None
    x, rss, theta_cov_scaled, scale_e = _solve_beside(block, E, b)
    n_eff = sum(len(blk) / problem.correlation_rows(i, lag) for blk, i in zip(blocks_b, block.used))
    dof = max(n_eff - n_cols, 1.0)
    s2 = max(rss / dof, 1.0)
    offsets = {problem.channels[i].name: x[n_base + block.starts[j]:n_base + block.starts[j + 1]].copy()
               for j, i in enumerate(block.kin)}
    theta = x[n_cols - q:] if q else np.zeros(0)
    theta_cov = theta_cov_scaled / np.outer(scale_e, scale_e) * s2 if q else np.zeros((0, 0))
    if theta0 is not None:
        theta = theta + np.asarray(theta0)[:q]
    if held:
        full_cov = np.zeros((q + held, q + held))
        full_cov[:q, :q] = theta_cov
        return Fit(h, nonlinear, np.concatenate([theta, np.asarray(theta0)[q:]]), full_cov, x[:n_base],
                   offsets, rss, n_eff, n_cols)
    return Fit(h, nonlinear, theta, theta_cov, x[:n_base], offsets, rss, n_eff, n_cols, theta0=theta0)


#: Smallest singular value, relative to the largest, of the scaled base block or of a hypothesis' scaled
#: columns beside it, for which :func:`solve` fits the two apart; below it the whole system is solved by
#: ``numpy.linalg.lstsq`` (whose cut-off, ε·max(n, k)·σ_max, lies below this on these problems).
SEPARABLE_CONDITION = 1e-8


@dataclass
class _BaseBlock:
    """The weighted base and offset columns of a problem's fit rows and prior rows, scaled to unit norm,
    with their thin QR factors (``q_factor`` None where the block is rank-deficient)."""

    used: list            # channels with fit rows and weight
    kin: list             # the kinematic and rolling channels (offset columns)
    starts: np.ndarray    # offset columns of each of ``kin``, from n_base on
    columns: np.ndarray | None   # (rows, width) weighted; kept only where there is no QR
    scale: np.ndarray     # (width,) column norms (1 where 0)
    prior_rhs: np.ndarray
    q_factor: np.ndarray | None
    r_factor: np.ndarray | None

    @property
    def width(self) -> int:
        """Base + offset columns."""
        return len(self.scale)

    @classmethod
    def factored(cls, used: list, kin: list, starts: np.ndarray, columns: np.ndarray,
                 prior_rhs: np.ndarray) -> "_BaseBlock":
        """The block of the weighted ``columns`` (rows, width), scaled and factored."""
        scale = np.linalg.norm(columns, axis=0)
        scale[scale == 0] = 1.0
        q_factor = r_factor = None
        if columns.shape[0] >= columns.shape[1] > 0:
            q_factor, r_factor = np.linalg.qr(columns / scale)
            d = np.abs(np.diag(r_factor))
            if d.min() < SEPARABLE_CONDITION * d.max():
                q_factor = r_factor = None
        if q_factor is None:
            return cls(used, kin, starts, columns, scale, prior_rhs, None, None)
        # the columns are (Q R)·scale where the whole system is needed
        return cls(used, kin, starts, None, scale, prior_rhs, q_factor, r_factor)


#: Base blocks :func:`solve` keeps in its cache, the most recently used (each is rows × columns floats: a
#: full campaign's 30–40 MB). A diagnosis fits one problem's hypotheses in a row and comes back to a
#: problem at most two others later, but for one in 350 fits.
BASE_BLOCKS_KEPT = 4


def _base_block(problem: Problem, model: IdentificationResult, cache: dict | None) -> _BaseBlock:
    """The base block of ``problem`` (:class:`_BaseBlock`), kept in ``cache`` for the
    :data:`BASE_BLOCKS_KEPT` problems used last."""
    kept = None if cache is None else cache.setdefault("base blocks", OrderedDict())
    if kept is not None and id(problem) in kept and kept[id(problem)][0] is problem:
        kept.move_to_end(id(problem))
        return kept[id(problem)][1]
    kin = [i for i, c in enumerate(problem.channels) if c.kind != "torque"]
    n_base = len(P1_NAMES)
    widths = [problem.channels[i].nuisance.shape[1] for i in kin]
    starts = np.concatenate([[0], np.cumsum(widths)]).astype(int)
    width = n_base + int(starts[-1])
    blocks, used = [], []
    for i, ch in enumerate(problem.channels):
        rows = problem.fit_rows[i]
        if not rows.any() or problem.weights[i] == 0:
            continue
        A = np.zeros((int(rows.sum()), width))
        if ch.kind == "torque":
            A[:, :n_base] = ch.base[rows]
        else:
            j = kin.index(i)
            A[:, n_base + starts[j]:n_base + starts[j + 1]] = ch.nuisance[rows]
        blocks.append(A * problem.weights[i])
        used.append(i)
    if problem.base_prior:
        P = np.zeros((n_base, width))
        P[:, :n_base] = np.diag(1.0 / base_prior_std(model))
        prior_rhs = np.zeros(n_base)
    elif problem.measured is not None:
        m = problem.measured
        P = np.zeros((len(m.index), width))
        P[np.arange(len(m.index)), list(m.index)] = 1.0 / m.std
        prior_rhs = np.asarray(m.delta / m.std, dtype=float)
    else:
        P, prior_rhs = np.zeros((0, width)), np.zeros(0)
    block = _BaseBlock.factored(used, kin, starts, np.vstack(blocks + [P]), prior_rhs)
    if kept is not None:
        kept[id(problem)] = (problem, block)
        while len(kept) > BASE_BLOCKS_KEPT:
            kept.popitem(last=False)
    return block


def _solve_beside(block: _BaseBlock, E: np.ndarray | None, b: np.ndarray):
    """Least squares of ``b`` on the base block and the hypothesis' columns ``E`` (rows as the block's;
    None: none): the solution (base, offsets, θ), the RSS, θ's covariance before its noise scale and
    column scaling (the θ block of ((A/s)ᵀ(A/s))⁺), and θ's column scale."""
    q = 0 if E is None else E.shape[1]
    scale_e = np.ones(q)
    if q:
        scale_e = np.linalg.norm(E, axis=0)
        scale_e[scale_e == 0] = 1.0
    Q, R = block.q_factor, block.r_factor
    if Q is not None:
        qtb = Q.T @ b
        if not q:
            x0 = solve_triangular(R, qtb)
            r = b - Q @ qtb
            return x0 / block.scale, float(r @ r), np.zeros((0, 0)), scale_e
        Es = E / scale_e
        qte = Q.T @ Es
        e_perp = Es - Q @ qte
        sv = np.linalg.svd(e_perp, compute_uv=False)
        if sv.min() >= SEPARABLE_CONDITION * max(sv.max(), 1.0):
            b_perp = b - Q @ qtb
            theta_s, *_ = np.linalg.lstsq(e_perp, b_perp, rcond=None)
            x0 = solve_triangular(R, qtb - qte @ theta_s)
            r = b_perp - e_perp @ theta_s
            return (np.concatenate([x0 / block.scale, theta_s / scale_e]), float(r @ r),
                    np.linalg.inv(e_perp.T @ e_perp), scale_e)
    columns = block.columns if block.columns is not None else (Q @ R) * block.scale
    A = columns if not q else np.hstack([columns, E])
    scale = np.concatenate([block.scale, scale_e])
    As = A / scale
    x, *_ = np.linalg.lstsq(As, b, rcond=None)
    r = b - As @ x
    cov = np.linalg.pinv(As.T @ As)
    return x / scale, float(r @ r), cov[block.width:, block.width:], scale_e


def base_prior_std(model) -> np.ndarray:
    """σ of the base parameters' prior, shape (10,), in the units of p₁. Raises ValueError when the model
    gives a parameter no positive, finite standard deviation (its prior would be a division by zero)."""
    std = np.asarray(model.std_vector, dtype=float)
    bad = ~(np.isfinite(std) & (std > 0))
    if bad.any():
        raise ValueError(f"model: the standard deviation of {', '.join(np.asarray(P1_NAMES)[bad])} must be "
                         f"positive and finite to bound the base parameters, got {std[bad].tolist()}")
    return PRIOR_STD_FACTOR * std


def f_test(base: Fit, ext: Fit, extra_dof: int, tested: int | None = None) -> float:
    """p-value of the RSS reduction from ``base`` to ``ext`` (F test with n/L effective rows).

    ``tested``: the coefficients ``ext`` frees beyond ``base`` (default: all of ``ext.theta``); a further
    effect fitted beside accepted ones, which are free in both fits, frees only its own. Counting the
    accepted effects' coefficients too would divide the reduction by too many degrees of freedom: on
    noise the test then rejects half as often as its level (2.5 % at 5 %), and a payload beside an
    incline and a rolling resistance is tested as 5 coefficients where its fit frees 2.
    ``extra_dof``: profiled non-linear parameters."""
    q = (len(ext.theta) if tested is None else int(tested)) + extra_dof
    dof = max(ext.n_eff - ext.n_params - extra_dof, 1.0)
    if ext.rss <= 0:
        return 0.0
    F = max(base.rss - ext.rss, 0.0) / q / (ext.rss / dof)
    return float(stats.f.sf(F, q, dof))


def presence(fit: Fit, tail: int) -> float:
    """p-value of the last ``tail`` effect coefficients being zero: a Wald test, θᵀ Σ_θ⁺ θ against χ²
    with rank(Σ_θ) degrees of freedom, Σ_θ from :func:`solve` (with n/L effective rows).

    The F test asks whether the data need a different level of the hypothesis than the reference run
    has (θ ≠ θ₀); this asks whether the level the data have is there at all (θ ≠ 0). Both must hold for
    an effect to be named: a reference with a structural level θ₀ ≠ 0 of a hypothesis makes data with
    none of it differ from the reference, but the verdict would then report a magnitude whose own
    interval holds zero. 1.0 when the coefficients have no covariance (nothing to test against)."""
    theta = np.asarray(fit.theta, dtype=float)[len(fit.theta) - tail:]
    cov = np.asarray(fit.theta_cov, dtype=float)[len(fit.theta) - tail:, len(fit.theta) - tail:]
    if not len(theta) or not np.any(cov):
        return 1.0
    rank = int(np.linalg.matrix_rank(cov))
    if rank == 0:
        return 1.0
    wald = float(theta @ np.linalg.pinv(cov) @ theta)
    return float(stats.chi2.sf(wald, rank))


def collinearity(problem: Problem, h: Hypothesis, nonlinear, cache: dict | None = None) -> dict:
    """R² of each effect column regressed on the base columns over the weighted fit rows of every
    channel, and the base parameters most correlated with it. The base columns are zero outside the
    torque channels: a hypothesis that also acts on kinematic or rolling channels (the wheel radius,
    whose torque column is a combination of base columns) is separable through them."""
    cols, base = [], []
    for i, ch in enumerate(problem.channels):
        rows = problem.fit_rows[i]
        if not rows.any():
            continue
        c = cached_columns(h, nonlinear, ch, cache)
        if c is None:
            continue
        cols.append(c[rows] * problem.weights[i])
        b = ch.base[rows] if ch.kind == "torque" else np.zeros((int(rows.sum()), len(P1_NAMES)))
        base.append(b * problem.weights[i])
    if not cols:
        return {"r2": 0.0, "correlated_with": [], "separable": True}
    C, B = np.vstack(cols), np.vstack(base)
    keep = np.linalg.norm(B, axis=0) > 0
    B = B[:, keep]
    names = [n for n, k in zip(P1_NAMES, keep) if k]
    r2 = []
    for j in range(C.shape[1]):
        c = C[:, j]
        if not np.any(c):
            continue
        x, *_ = np.linalg.lstsq(B, c, rcond=None)
        r2.append(1 - np.sum((c - B @ x) ** 2) / np.sum(c**2))
    corr = []
    for j in range(C.shape[1]):
        for k, n in enumerate(names):
            denom = np.linalg.norm(C[:, j]) * np.linalg.norm(B[:, k])
            if denom > 0 and abs(C[:, j] @ B[:, k]) / denom > 0.9:
                corr.append(n)
    worst = float(max(r2)) if r2 else 0.0
    return {"r2": worst, "correlated_with": sorted(set(corr)), "separable": worst < COLLINEAR_R2}


@dataclass
class Candidate:
    """One hypothesis' fitted result."""

    hypothesis: Hypothesis
    fit: Fit
    magnitude: Magnitude
    p_value: float
    evaluation: Evaluation
    identifiability: dict
    physical: bool
    significant: bool = False
    notes: list[str] = field(default_factory=list)
    #: Held-out comparison of the model the hypothesis is added to (the base fit, with the accepted
    #: effects in forward selection) and the extended fit: how far the residual shrinks once the effect
    #: is added. ``evaluation`` starts instead from the significance test's base (which ranks and gates):
    #: the level the reference run already has of the hypothesis. None: the two are the same.
    added_to_model: Evaluation | None = None
    #: Held-out comparison of the model as identified (base parameters unchanged, with the effects
    #: accepted before this one) and the same model with the effect added at its fitted level, in the
    #: channel ``shrink`` is evaluated in: the residual before and after adding the effect.
    #: ``shrink`` starts instead from the base fit, whose base parameters may already have absorbed
    #: part of an effect collinear with them. Where the base parameters are free (a model identified on
    #: these data) the base fit is the re-identified model, and this is ``shrink``. Always set by
    #: :func:`fit_hypothesis`.
    from_model: Evaluation | None = None
    #: p-value of the effect's fitted level being zero (:func:`presence`); 1.0 when not tested.
    presence_p: float = 1.0
    #: Named by a measurement outside the ground's fit (e.g. "set-point": the bus' torque set-point
    #: against the torque actual), with ``magnitude`` from that measurement: its ``fit`` is the first
    #: round's and is not added to the model (""): fitted on the ground's data.
    measured: str = ""

    @property
    def name(self) -> str:
        return self.hypothesis.name

    @property
    def shrink(self) -> Evaluation:
        """The held-out before/after of adding the effect to the model (``added_to_model``)."""
        return self.added_to_model if self.added_to_model is not None else self.evaluation

    @property
    def coefficients(self) -> dict[str, float]:
        """The hypothesis' own coefficients by parameter name. A further effect's fit is the joint fit
        with the accepted effects in the model, whose coefficients lead θ: its own are the last ones."""
        names = self.hypothesis.parameters
        theta = np.asarray(self.fit.theta, dtype=float)
        return dict(zip(names, theta[len(theta) - len(names):].tolist()))

    @property
    def coefficients_ci(self) -> dict[str, list[float]]:
        """Each of :attr:`coefficients`' 95 % interval, θ ± Z_95 σ with σ from the fit's covariance (the
        same σ as the presence test's, :func:`presence`): a coefficient the campaign does not determine shows
        it here (a payload's first moment along the chassis, docs/diagnosis.md, Limits) where the
        magnitude, a norm over the coefficients, may not."""
        names = self.hypothesis.parameters
        theta = np.asarray(self.fit.theta, dtype=float)
        cov = np.atleast_2d(np.asarray(self.fit.theta_cov, dtype=float))
        tail = range(len(theta) - len(names), len(theta))
        return {n: [float(x) for x in interval_95(theta[i], math.sqrt(max(cov[i, i], 0.0)))] for n, i in zip(names, tail)}


def fit_hypothesis(fit_problem: Problem, hold_problem: Problem, model: IdentificationResult,
                   h: Hypothesis, base: Fit, lag: int, sheet, cache: dict,
                   reference: dict | None = None, hold_tail: int | None = None) -> Candidate | None:
    """Profile the hypothesis' non-linear parameter, fit, test and evaluate it on held-out rows: from
    the test's base (the reference level θ₀, ``Candidate.evaluation``) and from ``base`` (the model it
    is added to, ``Candidate.added_to_model``).

    ``reference``: ``{non-linear value: θ₀}``, the hypothesis' level fitted on the model's own run; the
    test is then whether the data need more of it than the reference had (θ ≠ θ₀). ``hold_tail``: for
    a joint hypothesis (accepted effects + a new one) only its last ``hold_tail`` coefficients are held
    at θ₀ in the base it is tested against (default: all).

    The profile is the likelihood's: the grid point whose extension fits the data best (least weighted
    RSS) is taken, and tested beyond its own reference level. Chosen instead by the RSS removed beyond
    the reference level, the profile went where the reference run has little of the hypothesis rather
    than where the data have most (the wheel joints' Stribeck velocity came out 0.1 rad/s for 0.05 with
    a faster rotation step). The profile is constrained: of the grid points whose linear coefficients
    are physically admissible (``h.physical``) the best is taken; only when none is, the best of all
    (then reported as physically impossible). A short delay fits a long grid delay at a gain below its
    bound about as well as the right one at gain 1, and the unconstrained optimum would discard it."""
    held = len(h.parameters) if hold_tail is None else hold_tail
    profiled = _profile(fit_problem, model, h, base, lag, cache, reference, held)
    if profiled is None:
        return None
    best, test_base = profiled
    p_value = f_test(test_base, best, extra_dof=h.profiled, tested=held)
    other = _other_fold(fit_problem, hold_problem, model, h, base, lag, cache, reference, held)
    evaluation = evaluate(hold_problem, test_base, best, cache,
                          also=() if other is None else ((other.hold, other.test_base, other.best),))
    added = None if test_base is base else evaluate(
        hold_problem, base, best, cache, also=() if other is None else ((other.hold, other.base, other.best),))
    # With the base parameters free (a model identified on these data) the base fit is the model
    # re-identified on them, and adding the effect re-fits the parameters too: the shrink is the base
    # fit's. With the parameters held as identified, an effect they absorbed in part would be added on
    # top of what they already hold.
    from_model = added_to_identified(hold_problem, best, held, (added or evaluation).affected, cache,
                                     also=() if other is None else ((other.hold, other.best),)) \
        if fit_problem.base_prior else (added or evaluation)
    magnitude = h.magnitude(best.theta, best.theta_cov, best.nonlinear, sheet)
    ident_check = collinearity(fit_problem, h, best.nonlinear, cache)
    physical = plausible(h, best.theta)
    cand = Candidate(h, best, magnitude, p_value, evaluation, ident_check, physical, added_to_model=added,
                     from_model=from_model, presence_p=presence(best, held))
    if best.theta0 is not None and np.any(best.theta0 != 0):
        cand.notes.append("the model's own run already shows a level "
                          + ", ".join(f"{v:.3g}" for v in best.theta0) + " of it; tested beyond that")
    # The shrinkage's window-bootstrap interval is reported, not required: with the few held-out
    # windows of a short step (2–3 in a quick campaign) it is too unstable to gate on.
    beyond_reference = bool(p_value < ALPHA and physical and evaluation.confirms(MIN_SHRINK))
    cand.significant = beyond_reference and present(cand)
    if beyond_reference and not present(cand):
        cand.notes.append(f"differs from the reference run's level but is not there itself (its level is "
                          f"zero: p = {cand.presence_p:.2g}): not named")
    if not h.physical(best.theta):
        cand.notes.append("fitted sign or size is physically impossible for this effect")
    elif not physical:
        cand.notes.append(f"below the smallest size of practical relevance ({h.relevant:g}): not named")
    if evaluation.removed <= 0 < evaluation.shrink_affected:
        cand.notes.append(f"adds held-out residual overall ({-evaluation.removed:.3g} weighted) while it shrinks "
                          f"{evaluation.affected} by {100 * evaluation.shrink_affected:.0f} %: not confirmed")
    if not ident_check["separable"]:
        cand.notes.append("columns nearly collinear with "
                          + (", ".join(ident_check["correlated_with"]) or "the base columns together")
                          + ": separable only through the base model's uncertainty")
    return cand


def _profile(fit_problem: Problem, model: IdentificationResult, h: Hypothesis, base: Fit, lag: int,
             cache: dict, reference: dict | None, held: int) -> tuple[Fit, Fit] | None:
    """The profile's choice of :func:`fit_hypothesis` on ``fit_problem``: the best physically admissible
    grid point's fit (the best of all where none is), and the base its test compares it with: ``base``
    where there is no reference level, else the fit with the last ``held`` coefficients held at the
    reference level θ₀ of that grid point. None where the hypothesis has no columns."""
    fits = []
    for nonlinear in h.grid:
        theta0 = None if reference is None else reference.get(nonlinear)
        ext = solve(fit_problem, model, h, nonlinear, lag, cache, theta0=theta0)
        if ext is not None:
            fits.append((ext.rss, bool(h.physical(ext.theta)), ext, theta0))
    if not fits:
        return None
    admissible = [f for f in fits if f[1]] or fits
    _, _, best, theta0 = min(admissible, key=lambda f: f[0])
    test_base = base if theta0 is None else solve(fit_problem, model, h, best.nonlinear, lag, cache,
                                                  theta0=theta0, held=held)
    return best, test_base


def other_fold_base(fit_problem: Problem, hold_problem: Problem, model: IdentificationResult, base: Fit,
                    lag: int, cache: dict | None) -> tuple[Problem, Problem, Fit] | None:
    """The other fold of an alternate-window split (:func:`.problem.swapped`: its fit and held-out
    problems) and ``base``'s model (its effects at their non-linear values, none re-profiled) fitted on
    its fit windows, cached by ``base`` in ``cache`` (``base`` is the fit of ``fit_problem``, so it names
    the split); None where cross-fitting is off (``CROSS_FIT``), the held-out rows are a second run's or
    ``base``'s model has no column there."""
    swap = swapped(fit_problem, hold_problem) if CROSS_FIT else None
    if swap is None:
        return None
    fit_b, hold_b = swap
    cache = {} if cache is None else cache
    key = ("other fold's base", id(base))
    if key not in cache or cache[key][0] is not base:
        cache[key] = (base, solve(fit_b, model, base.hypothesis, base.nonlinear, lag, cache, theta0=base.theta0))
    base_b = cache[key][1]
    return None if base_b is None else (fit_b, hold_b, base_b)


@dataclass
class _Fold:
    """The other fold of a cross-fitted comparison: its held-out problem and its own fits."""

    hold: Problem
    base: Fit
    test_base: Fit
    best: Fit


def _other_fold(fit_problem: Problem, hold_problem: Problem, model: IdentificationResult, h: Hypothesis,
                base: Fit, lag: int, cache: dict, reference: dict | None, held: int) -> _Fold | None:
    """The hypothesis fitted again with the fit and held-out windows swapped (:func:`.problem.swapped`):
    its own profile, base fit and test base on the other windows, so that every window is held out
    from the fits it is evaluated by. None where cross-fitting is off, the held-out rows are a second
    run's or the hypothesis has no column in the other fold's fit windows (the comparison is then the
    first fold's alone)."""
    other = other_fold_base(fit_problem, hold_problem, model, base, lag, cache)
    if other is None:
        return None
    fit_b, hold_b, base_b = other
    profiled = _profile(fit_b, model, h, base_b, lag, cache, reference, held)
    if profiled is None:
        return None
    best_b, test_base_b = profiled
    return _Fold(hold_b, base_b, test_base_b, best_b)


def present(cand: Candidate) -> bool:
    """Whether the effect is there, not merely different from the reference run's level of it: its
    fitted level is not zero (``presence_p`` < ALPHA).

    Not also that adding it to the model as identified shrinks the residual (``from_model``): a model
    identified on the same run has absorbed part of an effect its parameters can mimic, and adding the
    whole effect to those parameters can grow the residual although the effect is there (a 10 ms
    actuator delay: −14 % from the model as identified, 80 % from the base fit)."""
    return cand.presence_p < ALPHA


def level_z(problem: Problem, model: IdentificationResult, h: Hypothesis, nonlinear, lag: int,
            cache: dict | None = None, theta0: np.ndarray | None = None) -> float | None:
    """One-sided z of a one-coefficient hypothesis' level beyond ``theta0`` (default 0):
    (θ − θ₀)/σ_θ fitted on ``problem``'s fit rows with the base parameters free within their prior.
    None if the hypothesis has no column there.

    Raises:
        ValueError: the hypothesis has more than one coefficient."""
    if len(h.parameters) != 1:
        raise ValueError(f"{h.label}: level_z needs a one-coefficient hypothesis")
    fit = solve(problem, model, h, nonlinear, lag, cache, theta0=theta0)
    return None if fit is None else coefficient_z(fit, 0)


def with_step_levels(h: Hypothesis, names: tuple[str, ...]) -> Hypothesis:
    """``h``'s columns followed by one Coulomb level per torque channel in ``names``: tanh(ṡ/ε) of the
    channel's own coordinate (ε of (16)), in that channel alone; coefficients ``h.parameters`` then
    ``names``. Shape per channel (n, len(h.parameters) + len(names)); None where neither acts."""
    width = len(h.parameters)

    def columns(ch: ChannelData, nonlinear):
        own = columns_on(h, ch, nonlinear)
        if ch.kind != "torque" or ch.name not in names:
            return None if own is None else np.hstack([own, np.zeros((len(own), len(names)))])
        out = np.zeros((len(ch.y), width + len(names)))
        if own is not None:
            out[:, :width] = own
        out[:, width + names.index(ch.name)] = np.tanh(ch.velocity / EPSILON)
        return out
    return replace(h, variant=f"{h.variant}+step levels", parameters=h.parameters + tuple(names),
                   columns=columns, resolve=None)


def level_beside_step_levels(problem: Problem, reference: Problem | None, model: IdentificationResult,
                             h: Hypothesis, nonlinear, lag: int, cache: dict | None = None
                             ) -> tuple[float, float] | None:
    """(z, σ) of a one-coefficient hypothesis' level on ``problem`` beside a free Coulomb level per
    fitted torque channel (:func:`with_step_levels`), every channel weighted by what that fit leaves of
    it (:func:`reweighted`); z beyond the level the reference run's channels hold under the same
    weights (beyond 0 without ``reference``). None if the hypothesis has no column there.

    For a level that is a low-speed shape (a friction peak) where each channel may carry its own
    Coulomb-like offset that no base parameter holds: a model identified on the data has one Coulomb
    coefficient for all its steps, fitted as a compromise between them, and each step keeps the
    difference. Left in, that offset counts as noise in the channel weights and hides the shape.

    Raises:
        ValueError: the hypothesis has more than one coefficient."""
    if len(h.parameters) != 1:
        raise ValueError(f"{h.label}: level_beside_step_levels needs a one-coefficient hypothesis")
    names = tuple(ch.name for i, ch in enumerate(problem.channels)
                  if ch.kind == "torque" and problem.fit_rows[i].any() and problem.weights[i] > 0)
    levelled = with_step_levels(h, names)
    first = solve(problem, model, levelled, nonlinear, lag, cache)
    if first is None:
        return None
    weighted = reweighted(problem, first, lag, cache)
    theta0 = None
    if reference is not None:
        by_name = dict(zip((c.name for c in weighted.channels), weighted.weights))
        ref_weights = np.array([by_name.get(c.name, w) for c, w in zip(reference.channels, reference.weights)])
        ref = solve(replace(reference, weights=ref_weights), model, levelled, nonlinear, lag, cache)
        theta0 = None if ref is None else ref.theta
    fit = solve(weighted, model, levelled, nonlinear, lag, cache, theta0=theta0)
    return coefficient_z(fit, 0), float(math.sqrt(fit.theta_cov[0, 0]))


def reweighted(problem: Problem, fit: Fit, lag: int, cache: dict | None = None,
               kinds: tuple[str, ...] | None = None) -> Problem:
    """The same problem with every channel weighted by 1/(σ_c √L_c), σ_c the RMS of what ``fit`` leaves
    of the channel's residual on its fit rows: the second step of feasible weighted least squares.

    :func:`make_problem` weights a channel by the RMS of the model's own residual, which holds whatever
    the model misses there — the effect under test included. Where one channel's residual is dominated
    by a term the fit then explains, that term has counted as noise and every coefficient's σ is
    inflated by it; weighting by what the fit leaves counts only the noise. A channel the fit leaves
    nothing of (a paired reference run's own channels), or one not fitted, keeps its weight.

    Args:
        problem: the problem ``fit`` was solved on (:func:`solve`).
        fit: its solution; what it leaves of a channel is :func:`.evaluation.predicted_residual` on
            the fit rows (its hypothesis' columns with the full θ, θ₀ included).
        lag: rows of the filter's correlation (:func:`.problem.channel_lag`).
        kinds: only channels of these kinds (``ChannelData.kind``: "torque", "kinematic", "rolling") are
            weighted again, the others keep their weight; None: every channel.
    """
    weights = problem.weights.copy()
    for i, ch in enumerate(problem.channels):
        rows = problem.fit_rows[i]
        if not rows.any() or weights[i] == 0 or (kinds is not None and ch.kind not in kinds):
            continue
        rms = float(np.sqrt(np.mean(predicted_residual(problem, i, fit, rows, cache) ** 2)))
        if rms > 0:
            weights[i] = 1.0 / (rms * math.sqrt(problem.correlation_rows(i, lag)))
    return replace(problem, weights=weights)


def coefficient_z(fit: Fit, index: int) -> float:
    """One-sided z of coefficient ``index`` of ``fit`` beyond its reference level (``fit.theta0``, 0 when
    none): (θ_i − θ₀,i)/σ_i with σ_i from ``fit.theta_cov``."""
    t0 = 0.0 if fit.theta0 is None else float(np.asarray(fit.theta0)[index])
    return float((fit.theta[index] - t0) / math.sqrt(max(fit.theta_cov[index, index], 1e-300)))


def reference_levels(problem: Problem, model: IdentificationResult, hypotheses, lag: int,
                     cache: dict) -> dict[str, dict]:
    """Every hypothesis' level θ₀ per non-linear value fitted on the model's own run (``problem`` with
    all rows as fit rows): what the model's source data already hold of each hypothesis — e.g. the
    stick-slip transients of any real friction that a Stribeck column also fits."""
    levels = {}
    for h in hypotheses:
        per = {}
        for nonlinear in h.grid:
            fit = solve(problem, model, h, nonlinear, lag, cache)
            if fit is not None:
                per[nonlinear] = fit.theta
        levels[h.label] = per
    return levels
