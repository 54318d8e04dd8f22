"""C99 code of the feed-forward law (21), generated with sympy from :mod:`ident.symbolic`.

The paper's feed-forward control (21) is

    u(q, s_dot_k, s_ddot_k, p) = [H_k^T(alpha) B(q)]^+ H_k^T(alpha) Theta(q, q_dot, q_ddot) p,

with q_dot = H_k s_dot_k (4) and q_ddot = H_dot_k s_dot_k + H_k s_ddot_k (20). This module builds, for
every motion mode k = 1..4, the two sympy matrices the C code needs,

* :func:`generalized_force` ``tau_k = H_k^T Theta p``, shape (n_k, 1) (N m or N per generalized
  coordinate), and
* :func:`reduced_input_matrix` ``H_k^T B``, shape (n_k, 4) (maps motor-side torques in N m to tau_k),

plus the mode-2 ICR relations :func:`f_icr` (alpha = f_ICR(alpha_v), (8)) and :func:`alpha_v_from_alpha`
(its inverse, the same formula as :func:`ident.kinematics.alpha_v_from_alpha`), and prints them with
``sympy.utilities.codegen.C99CodeGen(cse=True)`` (:func:`generate_c`). The pseudoinverse and the mode
dispatch are hand-written C (``fmu/c/feedforward/feedforward.c``): n_k <= 2, so
``M^+ = M^T (M M^T)^-1`` in closed form.

C arguments (all ``double``; arrays as pointers), the same for every generated function that uses them:

=============  =====  ==============================================================================
name           shape  meaning
=============  =====  ==============================================================================
``alpha``      (2,)   (alpha_l, alpha_r), rad
``alpha_v``    –      virtual steering angle of mode 2, rad (ignored by k = 1, 3, 4)
``s_dot``      (2,)   s_dot_k of (10)-(13) (rad/s or m/s); only the first n_k entries are read
``s_ddot``     (2,)   s_ddot_k, (rad/s^2 or m/s^2); only the first n_k entries are read
``p``          (11,)  p of (18): C_l, d_vl, d_cl, C_r, d_vr, d_cr, m_ch, C_ch, d_vw, d_cw, B_w (SI)
``geometry``   (4,)   (l, b, a, r), m
``i_G``        –      gear ratio (wheel torque = i_G motor torque)
``eps``        –      tanh smoothing of Coulomb friction, rad/s (> 0)
=============  =====  ==============================================================================

Matrix outputs are written row-major into the last pointer argument.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from functools import cache

import sympy as sp
from sympy.printing.c import C99CodePrinter
from sympy.printing.precedence import PRECEDENCE
from sympy.utilities.codegen import C99CodeGen

from qomni.ident import symbolic as S

PREFIX = "qomni_ff"
"""Prefix of every generated C function."""

GENERATED_NAME = "feedforward_generated"
"""Base name of the generated ``.c`` / ``.h`` files."""

N_GENERALIZED = {k: S.H(k).shape[1] for k in S.MODES}
"""n_k: number of generalized velocities of mode k (2, 2, 1, 1)."""

# --- the C arguments as sympy symbols -------------------------------------------------------------
ALPHA = sp.MatrixSymbol("alpha", 2, 1)
ALPHA_V = sp.Symbol("alpha_v", real=True)
S_DOT = sp.MatrixSymbol("s_dot", 2, 1)
S_DDOT = sp.MatrixSymbol("s_ddot", 2, 1)
P = sp.MatrixSymbol("p", len(S.PARAMETER_NAMES), 1)
GEOMETRY = sp.MatrixSymbol("geometry", 4, 1)
I_G = sp.Symbol("i_G", positive=True)
EPS = sp.Symbol("eps", positive=True)


def _to_c_arguments(expr):
    """Replace the symbols of :mod:`ident.symbolic` by the C arguments."""
    table = {S.alpha_l: ALPHA[0, 0], S.alpha_r: ALPHA[1, 0], S.alpha_v: ALPHA_V, S.i_G: I_G, S.eps: EPS}
    table.update({s: P[j, 0] for j, s in enumerate(S.p)})
    table.update({s: GEOMETRY[j, 0] for j, s in enumerate(S.GEOMETRY_SYMBOLS)})
    return expr.xreplace(table)


def _check_mode(k) -> int:
    if k not in S.MODES:
        raise ValueError(f"motion mode k must be one of {S.MODES}, got {k!r}")
    return int(k)


# --- the expressions ------------------------------------------------------------------------------
@cache
def generalized_velocities(k: int) -> tuple[sp.ImmutableMatrix, sp.ImmutableMatrix]:
    """q_dot = H_k s_dot_k (4) and q_ddot = H_dot_k s_dot_k + H_k s_ddot_k (20), each (9, 1), in the
    C arguments. Rates in H_dot_k are the consistent ones: alpha_dot = rows 3..4 of q_dot and (k = 2)
    alpha_v_dot = s_dot[0]. Raises ValueError for k not in 1..4."""
    k = _check_mode(k)
    Hk = S.H(k)
    n = Hk.shape[1]
    sd = sp.Matrix([S_DOT[i, 0] for i in range(n)])
    sdd = sp.Matrix([S_DDOT[i, 0] for i in range(n)])
    qd = Hk * sd
    rates = {S.alpha_l_dot: qd[3], S.alpha_r_dot: qd[4], S.alpha_v_dot: sd[0]}
    qdd = S.H_dot(k).xreplace(rates) * sd + Hk * sdd
    return (sp.ImmutableMatrix(_to_c_arguments(qd)), sp.ImmutableMatrix(_to_c_arguments(qdd)))


@cache
def generalized_force(k: int) -> sp.ImmutableMatrix:
    """tau_k = H_k^T Theta(q, q_dot, q_ddot) p of (19)/(21), shape (n_k, 1), in the C arguments
    (alpha, alpha_v for k = 2, s_dot, s_ddot, p, geometry, eps); units of s_dot_k's dual (N m for
    angles, N for x_ch / y_ch). Raises ValueError for k not in 1..4."""
    k = _check_mode(k)
    Hk = S.H(k)
    qd, qdd = generalized_velocities(k)
    Y = _to_c_arguments(S.regressor())
    rows = {S.qd[i]: qd[i] for i in range(9)} | {S.qdd[i]: qdd[i] for i in range(9)}
    rows = {_to_c_arguments(s): v for s, v in rows.items()}
    Theta_p = Y.xreplace(rows) * P.as_explicit()
    return sp.ImmutableMatrix(_to_c_arguments(Hk.T) * Theta_p)


@cache
def reduced_input_matrix(k: int) -> sp.ImmutableMatrix:
    """H_k^T B of (19)/(21), shape (n_k, 4), in the C arguments (alpha, alpha_v for k = 2, geometry,
    i_G): generalized force per motor-side torque. Raises ValueError for k not in 1..4."""
    return sp.ImmutableMatrix(_to_c_arguments(S.reduced_input_matrix(_check_mode(k))))


@cache
def f_icr() -> sp.ImmutableMatrix:
    """alpha = f_ICR(alpha_v) of (8), shape (2, 1), in the C arguments (alpha_v, geometry);
    from :func:`ident.symbolic.f_icr`."""
    return sp.ImmutableMatrix(_to_c_arguments(S.f_icr()))


@cache
def alpha_v_from_alpha() -> sp.Expr:
    """Inverse of (8), rad, in the C arguments (alpha, geometry): the mean of the path curvatures
    implied by the left and the right angle, ``kappa_l = 2 sin a_l / (l cos a_l + b sin a_l)``,
    ``kappa_r = 2 sin a_r / (l cos a_r - b sin a_r)``, ``alpha_v = atan(l (kappa_l + kappa_r) / 4)``;
    exact on the mode-2 manifold alpha = f_ICR(alpha_v) (same formula as
    :func:`ident.kinematics.alpha_v_from_alpha`)."""
    al, ar = ALPHA[0, 0], ALPHA[1, 0]
    l, b = GEOMETRY[0, 0], GEOMETRY[1, 0]
    kappa = (2 * sp.sin(al) / (l * sp.cos(al) + b * sp.sin(al))
             + 2 * sp.sin(ar) / (l * sp.cos(ar) - b * sp.sin(ar))) / 2
    return sp.atan(kappa * l / 2)


# --- C code -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GeneratedCode:
    """Generated C99 sources: ``c`` and ``h`` are the texts of ``<name>.c`` and ``<name>.h``;
    ``functions`` the C function names in the order generated."""

    name: str
    c: str
    h: str
    functions: tuple[str, ...]

    def files(self) -> dict[str, str]:
        """{file name: text} of the two files."""
        return {self.name + ".c": self.c, self.name + ".h": self.h}


_MODE_ARGUMENTS = (ALPHA, ALPHA_V, S_DOT, S_DDOT, P, GEOMETRY, EPS)
_HB_ARGUMENTS = (ALPHA, ALPHA_V, GEOMETRY, I_G)


def _routines(gen: C99CodeGen, prefix: str):
    out = []
    for k in S.MODES:
        n = N_GENERALIZED[k]
        tau = sp.MatrixSymbol("tau", n, 1)
        out.append(gen.routine(f"{prefix}_tau_{k}", sp.Eq(tau, generalized_force(k)),
                               argument_sequence=_MODE_ARGUMENTS + (tau,), global_vars=None))
        hb = sp.MatrixSymbol("HB", n, 4)
        out.append(gen.routine(f"{prefix}_HB_{k}", sp.Eq(hb, reduced_input_matrix(k)),
                               argument_sequence=_HB_ARGUMENTS + (hb,), global_vars=None))
    return out + _icr_routines(gen, prefix) + _derivative_routines(gen, prefix)


def _icr_routines(gen: C99CodeGen, prefix: str) -> list:
    """``<prefix>_f_icr`` (8) and ``<prefix>_alpha_v_from_alpha`` (its inverse)."""
    alpha_out = sp.MatrixSymbol("alpha_out", 2, 1)
    return [gen.routine(f"{prefix}_f_icr", sp.Eq(alpha_out, f_icr()),
                        argument_sequence=(ALPHA_V, GEOMETRY, alpha_out), global_vars=None),
            gen.routine(f"{prefix}_alpha_v_from_alpha", alpha_v_from_alpha(),
                        argument_sequence=(ALPHA, GEOMETRY), global_vars=None)]


class ProductPowerPrinter(C99CodePrinter):
    """C99 printer that writes integer powers as products (``(x*x)``, ``(1.0/(x*x*x))``) instead of ``pow``,
    so the binaries need no libm symbol newer than glibc 2.17 (glibc 2.29 versioned ``pow``, ``exp`` and
    ``log``: a binary linked against ``pow@GLIBC_2.29`` does not load on older systems) and integer powers
    are exact products rather than a library call. Other powers keep the C99 printer's form."""

    MAX_FACTORS = 8

    def _print_Pow(self, expr):
        exponent = expr.exp
        if exponent.is_Integer and 2 <= abs(int(exponent)) <= self.MAX_FACTORS:
            base = self.parenthesize(expr.base, PRECEDENCE["Mul"], strict=True)
            product = "(" + "*".join([base] * abs(int(exponent))) + ")"  # a Pow binds tighter than a product
            return product if exponent > 0 else f"(1.0/{product})"
        return super()._print_Pow(expr)


def _generate(routines_of, prefix: str, name: str, banner: str, generator: str) -> GeneratedCode:
    """Print the routines ``routines_of(gen, prefix)`` into ``<name>.c`` / ``<name>.h`` behind a comment
    that names ``generator`` (this module's function) and ends with the lines ``banner``."""
    for what, text in (("prefix", prefix), ("name", name)):
        if not text.isidentifier() or not text.isascii():
            raise ValueError(f"{what} must be a C identifier, got {text!r}")
    gen = C99CodeGen(project="qomni", printer=ProductPowerPrinter(), cse=True)
    routines = routines_of(gen, prefix)
    [(_, c_code), (_, h_code)] = gen.write(routines, name, header=False, empty=True)
    banner = (f"/* Generated by fmu.codegen from ident/symbolic.py (sympy {sp.__version__}, C99, cse, integer\n"
              " * powers as products).\n"
              f" * Do not edit: regenerate with fmu.codegen.{generator}().\n" + banner)
    return GeneratedCode(name=name, c=banner + _mark_unused_arguments(c_code), h=banner + h_code,
                         functions=tuple(r.name for r in routines))


_FUNCTION = re.compile(r"^(?:void|double) \w+\(([^)]*)\) \{\n(.*?)^\}\n", re.S | re.M)


def _mark_unused_arguments(c_code: str) -> str:
    """Add ``(void)name;`` for arguments a generated function does not use (every mode-k function has
    the same signature), so the sources compile cleanly with -Wall -Wextra."""
    def fix(m: re.Match) -> str:
        names = [a.split()[-1].lstrip("*") for a in m.group(1).split(",")]
        unused = [n for n in names if not re.search(rf"\b{n}\b", m.group(2))]
        head = m.group(0)[: m.start(2) - m.start(0)]
        return head + "".join(f"   (void){n};\n" for n in unused) + m.group(0)[m.start(2) - m.start(0):]
    return _FUNCTION.sub(fix, c_code)


_BANNER = (" * Feed-forward law (21) of the paper: tau_k = H_k^T Theta p and H_k^T B per motion mode k,\n"
           " * the mode-2 ICR relation f_ICR (8) with its inverse, and their exact partial derivatives by\n"
           " * alpha, alpha_v, s_dot, s_ddot. Matrix outputs row-major. */\n")


@cache
def generate_c(prefix: str = PREFIX, name: str = GENERATED_NAME) -> GeneratedCode:
    """Print all expressions of this module as C99 (common subexpressions eliminated).

    Functions (``<prefix>_...``; argument meanings in the module docstring):

    * ``void <prefix>_tau_<k>(double *alpha, double alpha_v, double *s_dot, double *s_ddot,
      double *p, double *geometry, double eps, double *tau)`` -- tau (n_k,), k = 1..4;
    * ``void <prefix>_HB_<k>(double *alpha, double alpha_v, double *geometry, double i_G,
      double *HB)`` -- H_k^T B (n_k, 4) row-major;
    * ``void <prefix>_f_icr(double alpha_v, double *geometry, double *alpha_out)`` -- (2,);
    * ``double <prefix>_alpha_v_from_alpha(double *alpha, double *geometry)``;
    * the exact partial derivatives (:data:`KNOWNS`): ``void <prefix>_dtau_<k>(<as tau>, double *dtau)``
      (n_k, 7) (:func:`generalized_force_jacobian`), ``void <prefix>_dHB_<k>(<as HB>, double *dHB)``
      (3 n_k, 4) (:func:`reduced_input_matrix_derivatives`), ``void <prefix>_df_icr(double alpha_v,
      double *geometry, double *df)`` (2,) and ``void <prefix>_dalpha_v_from_alpha(double *alpha,
      double *geometry, double *grad)`` (2,) (:func:`icr_derivatives`).

    Returns:
        :class:`GeneratedCode` with the ``.c`` (includes ``<name>.h`` and ``math.h``) and ``.h`` texts.
    Raises:
        ValueError: ``prefix`` or ``name`` is not a C identifier.
    """
    return _generate(_routines, prefix, name, _BANNER, "generate_c")


# --- plant: forward dynamics of (19)/(20) per motion mode ----------------------------------------------
PLANT_PREFIX = "qomni_plant"
"""Prefix of every generated C function of the plant model."""

PLANT_GENERATED_NAME = "plant_generated"
"""Base name of the generated plant ``.c`` / ``.h`` files."""

U = sp.MatrixSymbol("u", 4, 1)
"""C argument: motor-side torques (fl, rl, fr, rr), N m."""


@cache
def plant_dynamics(k: int) -> tuple[sp.ImmutableMatrix, sp.ImmutableMatrix]:
    """Forward dynamics of mode k in the C arguments (alpha, alpha_v for k = 2, s_dot, u, p, geometry,
    i_G, eps): ``(s_ddot_k, q_dot)`` with shapes (n_k, 1) and (9, 1), where q_dot = H_k s_dot_k (4) and

        H_k^T M H_k s_ddot_k = H_k^T B u - H_k^T Theta(q, q_dot, H_dot_k s_dot_k) p     ((19) with (20)),

    the same equation as :func:`ident.dynamics.forward_dynamics`. The n_k x n_k system (n_k <= 2) is
    solved in closed form (adjugate / determinant). Raises ValueError for k not in 1..4."""
    k = _check_mode(k)
    n = N_GENERALIZED[k]
    Hk = _to_c_arguments(S.H(k))
    qd, _ = generalized_velocities(k)
    tau_bias = generalized_force(k).xreplace({S_DDOT[i, 0]: 0 for i in range(2)})
    tau_u = reduced_input_matrix(k) * U.as_explicit()
    Mk = sp.Matrix(Hk.T * _to_c_arguments(S.mass_matrix()) * Hk).applyfunc(sp.expand)
    rhs = sp.Matrix(tau_u - tau_bias)
    if n == 1:
        sdd = rhs / Mk[0, 0]
    else:
        det = Mk[0, 0] * Mk[1, 1] - Mk[0, 1] * Mk[1, 0]
        sdd = sp.Matrix([Mk[1, 1] * rhs[0] - Mk[0, 1] * rhs[1], Mk[0, 0] * rhs[1] - Mk[1, 0] * rhs[0]]) / det
    return sp.ImmutableMatrix(sdd), sp.ImmutableMatrix(qd)


@cache
def kinematic_model(k: int) -> sp.ImmutableMatrix:
    """H_k(alpha) of (4), shape (9, n_k), in the C arguments (alpha, alpha_v for k = 2, geometry)."""
    return sp.ImmutableMatrix(_to_c_arguments(S.H(_check_mode(k))))


_PLANT_ARGUMENTS = (ALPHA, ALPHA_V, S_DOT, U, P, GEOMETRY, I_G, EPS)
_PLANT_BANNER = (" * Plant model: forward dynamics (19)/(20) s_ddot_k and q_dot = H_k s_dot_k per motion mode\n"
                 " * k, H_k (4), and the mode-2 ICR relation f_ICR (8) with its inverse. Matrices row-major. */\n")


@cache
def generate_plant_c(prefix: str = PLANT_PREFIX, name: str = PLANT_GENERATED_NAME) -> GeneratedCode:
    """C99 code of the plant model (common subexpressions eliminated). Functions:

    * ``void <prefix>_rhs_<k>(double *alpha, double alpha_v, double *s_dot, double *u, double *p,
      double *geometry, double i_G, double eps, double *s_ddot, double *q_dot)`` -- s_ddot (n_k,),
      q_dot (9,), k = 1..4 (:func:`plant_dynamics`);
    * ``void <prefix>_H_<k>(double *alpha, double alpha_v, double *geometry, double *H)`` -- (9, n_k);
    * ``void <prefix>_f_icr(double alpha_v, double *geometry, double *alpha_out)``,
      ``double <prefix>_alpha_v_from_alpha(double *alpha, double *geometry)``.

    Raises:
        ValueError: ``prefix`` or ``name`` is not a C identifier.
    """
    return _generate(_plant_routines, prefix, name, _PLANT_BANNER, "generate_plant_c")


def _plant_routines(gen: C99CodeGen, prefix: str) -> list:
    routines = []
    for k in S.MODES:
        n = N_GENERALIZED[k]
        sdd_out, qd_out = sp.MatrixSymbol("s_ddot", n, 1), sp.MatrixSymbol("q_dot", 9, 1)
        sdd, qd = plant_dynamics(k)
        routines.append(gen.routine(f"{prefix}_rhs_{k}", [sp.Eq(sdd_out, sdd), sp.Eq(qd_out, qd)],
                                    argument_sequence=_PLANT_ARGUMENTS + (sdd_out, qd_out), global_vars=None))
        h_out = sp.MatrixSymbol("H", 9, n)
        routines.append(gen.routine(f"{prefix}_H_{k}", sp.Eq(h_out, kinematic_model(k)),
                                    argument_sequence=(ALPHA, ALPHA_V, GEOMETRY, h_out), global_vars=None))
    return routines + _icr_routines(gen, prefix)


__all__ = ["PREFIX", "GENERATED_NAME", "N_GENERALIZED", "ALPHA", "ALPHA_V", "S_DOT", "S_DDOT", "P",
           "GEOMETRY", "I_G", "EPS", "generalized_velocities", "generalized_force",
           "reduced_input_matrix", "f_icr", "alpha_v_from_alpha", "GeneratedCode", "generate_c",
           "PLANT_PREFIX", "PLANT_GENERATED_NAME", "U", "plant_dynamics", "kinematic_model", "generate_plant_c",
           "ProductPowerPrinter", "KNOWNS", "generalized_force_jacobian", "reduced_input_matrix_derivatives",
           "icr_derivatives"]


# --- feed-forward: exact partial derivatives of (21) ------------------------------------------------------
KNOWNS = (ALPHA[0, 0], ALPHA[1, 0], ALPHA_V, S_DOT[0, 0], S_DOT[1, 0], S_DDOT[0, 0], S_DDOT[1, 0])
"""The C arguments the derivatives are taken with respect to, in this order (the FMU inputs q.alpha_l,
q.alpha_r, alpha_v, s_dot[1], s_dot[2], s_ddot[1], s_ddot[2]); (21) reads no other input."""


@cache
def generalized_force_jacobian(k: int) -> sp.ImmutableMatrix:
    """d tau_k / d(alpha_l, alpha_r, alpha_v, s_dot, s_ddot) of :func:`generalized_force`, shape (n_k, 7),
    partial derivatives (alpha and alpha_v independent). Raises ValueError for k not in 1..4."""
    return sp.ImmutableMatrix(sp.Matrix(generalized_force(k)).jacobian(sp.Matrix(KNOWNS)))


@cache
def reduced_input_matrix_derivatives(k: int) -> sp.ImmutableMatrix:
    """d(H_k^T B) / d(alpha_l, alpha_r, alpha_v) stacked: rows 3 i .. 3 i + 2 ... shape (3 n_k, 4), block
    j (rows j n_k .. j n_k + n_k - 1) the derivative by the j-th of (alpha_l, alpha_r, alpha_v). Raises
    ValueError for k not in 1..4."""
    hb = sp.Matrix(reduced_input_matrix(k))
    return sp.ImmutableMatrix(sp.Matrix.vstack(*(hb.diff(x) for x in KNOWNS[:3])))


@cache
def icr_derivatives() -> tuple[sp.ImmutableMatrix, sp.ImmutableMatrix]:
    """(f_ICR'(alpha_v) of (8), shape (2, 1); the gradient of :func:`alpha_v_from_alpha` by (alpha_l,
    alpha_r), shape (1, 2)): the chain rule of mode 2, where alpha and alpha_v are tied."""
    grad = sp.Matrix([[alpha_v_from_alpha().diff(ALPHA[0, 0]), alpha_v_from_alpha().diff(ALPHA[1, 0])]])
    return sp.ImmutableMatrix(sp.Matrix(f_icr()).diff(ALPHA_V)), sp.ImmutableMatrix(grad)


def _derivative_routines(gen: C99CodeGen, prefix: str) -> list:
    out = []
    for k in S.MODES:
        n = N_GENERALIZED[k]
        dtau = sp.MatrixSymbol("dtau", n, len(KNOWNS))
        out.append(gen.routine(f"{prefix}_dtau_{k}", sp.Eq(dtau, generalized_force_jacobian(k)),
                               argument_sequence=_MODE_ARGUMENTS + (dtau,), global_vars=None))
        dhb = sp.MatrixSymbol("dHB", 3 * n, 4)
        out.append(gen.routine(f"{prefix}_dHB_{k}", sp.Eq(dhb, reduced_input_matrix_derivatives(k)),
                               argument_sequence=_HB_ARGUMENTS + (dhb,), global_vars=None))
    df, grad = icr_derivatives()
    df_out, grad_out = sp.MatrixSymbol("df", 2, 1), sp.MatrixSymbol("grad", 1, 2)
    out.append(gen.routine(f"{prefix}_df_icr", sp.Eq(df_out, df), argument_sequence=(ALPHA_V, GEOMETRY, df_out),
                           global_vars=None))
    out.append(gen.routine(f"{prefix}_dalpha_v_from_alpha", sp.Eq(grad_out, grad),
                           argument_sequence=(ALPHA, GEOMETRY, grad_out), global_vars=None))
    return out
