/* feedforward.c -- feed-forward control law (21); see feedforward.h. */
#include "feedforward.h"

#include <math.h>
#include <string.h>

#include "feedforward_generated.h"

#define RANK_TOL 1e-12 /* det(M M^T) <= RANK_TOL trace(M M^T)^2: treat M as rank deficient */

void qomni_ff_pinv_apply(int n, const double *M, const double *tau, double u[4]) {
    double g00 = 0.0, g01 = 0.0, g11 = 0.0;
    for (int j = 0; j < 4; j++) {
        g00 += M[j] * M[j];
        if (n == 2) {
            g01 += M[j] * M[4 + j];
            g11 += M[4 + j] * M[4 + j];
        }
    }
    double trace = g00 + g11;
    if (!(trace > 0.0)) { /* M = 0: M^+ = 0 */
        for (int j = 0; j < 4; j++) u[j] = 0.0;
        return;
    }
    if (n == 1) {
        for (int j = 0; j < 4; j++) u[j] = M[j] * tau[0] / g00;
        return;
    }
    double det = g00 * g11 - g01 * g01;
    if (det > RANK_TOL * trace * trace) { /* full row rank: M^+ = M^T (M M^T)^-1 */
        double w0 = (g11 * tau[0] - g01 * tau[1]) / det;
        double w1 = (g00 * tau[1] - g01 * tau[0]) / det;
        for (int j = 0; j < 4; j++) u[j] = M[j] * w0 + M[4 + j] * w1;
    } else { /* rank 1: M^+ = M^T / ||M||_F^2 */
        for (int j = 0; j < 4; j++) u[j] = (M[j] * tau[0] + M[4 + j] * tau[1]) / trace;
    }
}

/* Check the arguments and set the steering angles a and alpha_v *av the mode reads (mode 2: one from the
 * other). Returns 0, else 1 with *error set. */
static int prepare(int k, const double alpha[2], double alpha_v, bool alpha_v_given, const double geometry[4],
                   double i_G, double eps, double a[2], double *av, const char **error) {
    if (k < 1 || k > 4) {
        *error = "motion mode k must be 1, 2, 3 or 4";
        return 1;
    }
    if (!(geometry[0] > 0.0) || !(geometry[1] > 0.0) || !(geometry[3] > 0.0)) {
        *error = "geometry l, b and r must be > 0";
        return 1;
    }
    if (!(i_G > 0.0)) {
        *error = "gear ratio i_G must be > 0";
        return 1;
    }
    if (!(eps > 0.0)) {
        *error = "tanh smoothing eps must be > 0 rad/s";
        return 1;
    }
    double g[4] = {geometry[0], geometry[1], geometry[2], geometry[3]};
    a[0] = alpha[0];
    a[1] = alpha[1];
    *av = 0.0;
    if (k == 2) {
        double av_max = atan2(g[0], g[1]);
        if (alpha_v_given) {
            if (!(fabs(alpha_v) <= av_max + 1e-12)) {
                *error = "mode 2: |alpha_v| must be <= arctan(l/b)";
                return 1;
            }
            *av = alpha_v;
            qomni_ff_f_icr(*av, g, a);
        } else {
            *av = qomni_ff_alpha_v_from_alpha(a, g);
            if (!isfinite(*av) || !(fabs(*av) <= av_max + 1e-12)) {
                *error = "mode 2: no virtual steering angle alpha_v for these alpha_l, alpha_r "
                         "(far from the mode-2 configuration f_ICR)";
                return 1;
            }
        }
    }
    return 0;
}

/* tau_k (n_k,) and H_k^T B (n_k x 4) at a, av; with dtau, dHB not NULL also their partial derivatives
 * (n_k x 7 and 3 n_k x 4, feedforward_generated.h). The generated functions take non-const pointers. */
static void evaluate(int k, double a[2], double av, const double s_dot[2], const double s_ddot[2],
                     const double p[QOMNI_FF_N_PARAMETERS], const double geometry[4], double i_G, double eps,
                     double tau[2], double HB[8], double *dtau, double *dHB) {
    double g[4], pp[QOMNI_FF_N_PARAMETERS], sd[2] = {s_dot[0], s_dot[1]}, sdd[2] = {s_ddot[0], s_ddot[1]};
    memcpy(g, geometry, sizeof g);
    memcpy(pp, p, sizeof pp);
    switch (k) {
    case 1:
        qomni_ff_tau_1(a, av, sd, sdd, pp, g, eps, tau);
        qomni_ff_HB_1(a, av, g, i_G, HB);
        if (dtau) qomni_ff_dtau_1(a, av, sd, sdd, pp, g, eps, dtau);
        if (dHB) qomni_ff_dHB_1(a, av, g, i_G, dHB);
        break;
    case 2:
        qomni_ff_tau_2(a, av, sd, sdd, pp, g, eps, tau);
        qomni_ff_HB_2(a, av, g, i_G, HB);
        if (dtau) qomni_ff_dtau_2(a, av, sd, sdd, pp, g, eps, dtau);
        if (dHB) qomni_ff_dHB_2(a, av, g, i_G, dHB);
        break;
    case 3:
        qomni_ff_tau_3(a, av, sd, sdd, pp, g, eps, tau);
        qomni_ff_HB_3(a, av, g, i_G, HB);
        if (dtau) qomni_ff_dtau_3(a, av, sd, sdd, pp, g, eps, dtau);
        if (dHB) qomni_ff_dHB_3(a, av, g, i_G, dHB);
        break;
    default:
        qomni_ff_tau_4(a, av, sd, sdd, pp, g, eps, tau);
        qomni_ff_HB_4(a, av, g, i_G, HB);
        if (dtau) qomni_ff_dtau_4(a, av, sd, sdd, pp, g, eps, dtau);
        if (dHB) qomni_ff_dHB_4(a, av, g, i_G, dHB);
        break;
    }
}

int qomni_feedforward(int k, const double alpha[2], double alpha_v, bool alpha_v_given, const double s_dot[2],
                      const double s_ddot[2], const double p[QOMNI_FF_N_PARAMETERS], const double geometry[4],
                      double i_G, double eps, double u[4], const char **error) {
    const char *dummy;
    if (!error) error = &dummy;
    double a[2], av, tau[2] = {0.0, 0.0}, HB[8] = {0.0}, out[4];
    if (prepare(k, alpha, alpha_v, alpha_v_given, geometry, i_G, eps, a, &av, error)) return 1;
    evaluate(k, a, av, s_dot, s_ddot, p, geometry, i_G, eps, tau, HB, NULL, NULL);
    qomni_ff_pinv_apply(k <= 2 ? 2 : 1, HB, tau, out);
    for (int j = 0; j < 4; j++) {
        if (!isfinite(out[j])) {
            *error = "non-finite motor torque (check inputs and parameters)";
            return 1;
        }
    }
    memcpy(u, out, sizeof out);
    return 0;
}

/* du = d(M^+ tau) for M (n x 4) moving by dM and tau by dtau, on the same branch as qomni_ff_pinv_apply:
 * full row rank u = M^T w, w = G tau, G = (M M^T)^-1: du = dM^T w + M^T G (dtau - dM u - M dM^T w);
 * M^T tau / s with s = ||M||_F^2 (n = 1, rank 1): du = (dM^T tau + M^T dtau - u ds) / s, ds = 2 <M, dM>. */
static void pinv_derivative(int n, const double *M, const double *dM, const double *tau, const double *dtau,
                            double du[4]) {
    double g00 = 0.0, g01 = 0.0, g11 = 0.0, ds = 0.0, u[4];
    for (int j = 0; j < 4; j++) {
        g00 += M[j] * M[j];
        ds += 2.0 * M[j] * dM[j];
        if (n == 2) {
            g01 += M[j] * M[4 + j];
            g11 += M[4 + j] * M[4 + j];
            ds += 2.0 * M[4 + j] * dM[4 + j];
        }
    }
    double trace = g00 + g11, det = g00 * g11 - g01 * g01;
    qomni_ff_pinv_apply(n, M, tau, u);
    if (!(trace > 0.0)) {
        for (int j = 0; j < 4; j++) du[j] = 0.0;
    } else if (n == 2 && det > RANK_TOL * trace * trace) {
        double w0 = (g11 * tau[0] - g01 * tau[1]) / det, w1 = (g00 * tau[1] - g01 * tau[0]) / det, z[4];
        double r0 = dtau[0], r1 = dtau[1];
        for (int j = 0; j < 4; j++) {
            z[j] = dM[j] * w0 + dM[4 + j] * w1; /* dM^T w */
            r0 -= dM[j] * u[j] + M[j] * z[j];
            r1 -= dM[4 + j] * u[j] + M[4 + j] * z[j];
        }
        double v0 = (g11 * r0 - g01 * r1) / det, v1 = (g00 * r1 - g01 * r0) / det; /* G r */
        for (int j = 0; j < 4; j++) du[j] = z[j] + M[j] * v0 + M[4 + j] * v1;
    } else {
        for (int j = 0; j < 4; j++) {
            double t = dM[j] * tau[0] + M[j] * dtau[0];
            if (n == 2) t += dM[4 + j] * tau[1] + M[4 + j] * dtau[1];
            du[j] = (t - u[j] * ds) / trace;
        }
    }
}

int qomni_feedforward_jacobian(int k, const double alpha[2], double alpha_v, bool alpha_v_given,
                               const double s_dot[2], const double s_ddot[2], const double p[QOMNI_FF_N_PARAMETERS],
                               const double geometry[4], double i_G, double eps,
                               double J[4 * QOMNI_FF_N_KNOWNS], const char **error) {
    const char *dummy;
    if (!error) error = &dummy;
    double a[2], av, tau[2] = {0.0, 0.0}, HB[8] = {0.0}, dtau[2 * QOMNI_FF_N_KNOWNS] = {0.0}, dHB[24] = {0.0};
    if (prepare(k, alpha, alpha_v, alpha_v_given, geometry, i_G, eps, a, &av, error)) return 1;
    evaluate(k, a, av, s_dot, s_ddot, p, geometry, i_G, eps, tau, HB, dtau, dHB);
    int n = k <= 2 ? 2 : 1;
    /* chain rule of mode 2: alpha = f_ICR(alpha_v) given alpha_v, else alpha_v = alpha_v(alpha) */
    double w[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}; /* d(alpha_l, alpha_r, alpha_v) / d(known 0..2) */
    if (k == 2 && alpha_v_given) {
        double df[2], g[4] = {geometry[0], geometry[1], geometry[2], geometry[3]};
        qomni_ff_df_icr(av, g, df);
        w[0][0] = w[1][1] = 0.0;
        w[0][2] = df[0];
        w[1][2] = df[1];
    } else if (k == 2) {
        double grad[2], g[4] = {geometry[0], geometry[1], geometry[2], geometry[3]};
        qomni_ff_dalpha_v_from_alpha(a, g, grad);
        w[2][0] = grad[0];
        w[2][1] = grad[1];
        w[2][2] = 0.0;
    } else {
        w[2][2] = 0.0; /* modes 1, 3, 4 read no alpha_v */
    }
    for (int x = 0; x < QOMNI_FF_N_KNOWNS; x++) {
        double dt[2] = {0.0, 0.0}, dM[8] = {0.0}, du[4];
        for (int i = 0; i < n; i++) {
            if (x < 3) {
                for (int c = 0; c < 3; c++) {
                    dt[i] += dtau[i * QOMNI_FF_N_KNOWNS + c] * w[c][x];
                    for (int j = 0; j < 4; j++) dM[i * 4 + j] += dHB[(c * n + i) * 4 + j] * w[c][x];
                }
            } else {
                dt[i] = dtau[i * QOMNI_FF_N_KNOWNS + x];
            }
        }
        pinv_derivative(n, HB, dM, tau, dt, du);
        for (int j = 0; j < 4; j++) {
            if (!isfinite(du[j])) {
                *error = "non-finite derivative of the motor torque (check inputs and parameters)";
                return 1;
            }
            J[j * QOMNI_FF_N_KNOWNS + x] = du[j];
        }
    }
    return 0;
}
