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

int qomni_feedforward(int k, const double alpha[2], double alpha_v, bool alpha_v_given, const double s_dot[2],
                      const double s_ddot[2], const double p[QOMNI_FF_N_PARAMETERS], const double geometry[4],
                      double i_G, double eps, double u[4], const char **error) {
    const char *dummy;
    if (!error) error = &dummy;
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
    /* the generated functions take non-const pointers: work on copies */
    double a[2] = {alpha[0], alpha[1]}, g[4], pp[QOMNI_FF_N_PARAMETERS], sd[2] = {s_dot[0], s_dot[1]};
    double sdd[2] = {s_ddot[0], s_ddot[1]};
    memcpy(g, geometry, sizeof g);
    memcpy(pp, p, sizeof pp);
    double av = 0.0;
    if (k == 2) {
        double av_max = atan2(g[0], g[1]);
        if (alpha_v_given) {
            if (!(fabs(alpha_v) <= av_max + 1e-12)) {
                *error = "mode 2: |alpha_v| must be <= arctan(l/b)";
                return 1;
            }
            av = alpha_v;
            qomni_ff_f_icr(av, g, a);
        } else {
            av = qomni_ff_alpha_v_from_alpha(a, g);
            if (!isfinite(av) || !(fabs(av) <= av_max + 1e-12)) {
                *error = "mode 2: no virtual steering angle alpha_v for these alpha_l, alpha_r "
                         "(far from the mode-2 configuration f_ICR)";
                return 1;
            }
        }
    }
    double tau[2] = {0.0, 0.0}, HB[8] = {0.0};
    switch (k) {
    case 1:
        qomni_ff_tau_1(a, av, sd, sdd, pp, g, eps, tau);
        qomni_ff_HB_1(a, av, g, i_G, HB);
        break;
    case 2:
        qomni_ff_tau_2(a, av, sd, sdd, pp, g, eps, tau);
        qomni_ff_HB_2(a, av, g, i_G, HB);
        break;
    case 3:
        qomni_ff_tau_3(a, av, sd, sdd, pp, g, eps, tau);
        qomni_ff_HB_3(a, av, g, i_G, HB);
        break;
    default:
        qomni_ff_tau_4(a, av, sd, sdd, pp, g, eps, tau);
        qomni_ff_HB_4(a, av, g, i_G, HB);
        break;
    }
    double out[4];
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
