/* plant.c -- hybrid plant model (19)/(20) with mode transitions at rest; see plant.h and the module
 * docstring of fmu/plant_reference.py (the same algorithm in numpy, used by the tests). */
#include "plant.h"

#include <math.h>
#include <stdbool.h>
#include <string.h>

#include "plant_generated.h"

#define N_Y 12 /* integrated part of the state (everything but k) */
#define PI_2 1.57079632679489661923

enum { J_C_L = 0, J_D_VL, J_D_CL, J_C_R, J_D_VR, J_D_CR, J_M_CH, J_C_CH, J_D_VW, J_D_CW, J_B_W };

/* the generated functions take non-const pointers: every call works on this copy */
typedef struct {
    double p[QOMNI_PLANT_N_PARAMETERS];
    double g[4];
    double i_G, eps;
    const QomniPlantParameters *P;
} Model;

static void model_of(const QomniPlantParameters *P, Model *m) {
    memcpy(m->p, P->p, sizeof m->p);
    memcpy(m->g, P->geometry, sizeof m->g);
    m->i_G = P->i_G;
    m->eps = P->eps;
    m->P = P;
}

static int n_of(int k) { return k <= 2 ? 2 : 1; }

/* chassis column of H_k: mode 2 x_ch (column 1), modes 3 and 4 their only column */
static int chassis_column(int k) { return k == 2 ? 1 : 0; }

static void kinematic_model(Model *m, int k, double alpha[2], double alpha_v, double *H) {
    switch (k) {
    case 1: qomni_plant_H_1(alpha, alpha_v, m->g, H); break;
    case 2: qomni_plant_H_2(alpha, alpha_v, m->g, H); break;
    case 3: qomni_plant_H_3(alpha, alpha_v, m->g, H); break;
    default: qomni_plant_H_4(alpha, alpha_v, m->g, H); break;
    }
}

int qomni_plant_check(const QomniPlantParameters *P, const char **error) {
    const double *p = P->p;
    for (int j = 0; j < QOMNI_PLANT_N_PARAMETERS; j++) {
        if (!isfinite(p[j]) || p[j] < 0.0) {
            *error = "the parameters p (18) must be finite and >= 0";
            return 1;
        }
    }
    if (!(p[J_C_L] > 0.0 && p[J_C_R] > 0.0 && p[J_M_CH] > 0.0 && p[J_C_CH] > 0.0 && p[J_B_W] > 0.0)) {
        *error = "the inertia parameters C_l, C_r, m_ch, C_ch, B_w must be > 0";
        return 1;
    }
    const double *g = P->geometry;
    if (!(g[0] > 0.0 && g[1] > 0.0 && g[2] >= 0.0 && g[3] > 0.0 && isfinite(g[0] + g[1] + g[2] + g[3]))) {
        *error = "geometry: l, b, r must be > 0 and a >= 0 (finite)";
        return 1;
    }
    if (!(P->steering_limit > 0.0 && P->steering_limit <= PI_2 + 1e-12)) {
        *error = "steering_limit must be in (0, pi/2]";
        return 1;
    }
    if (!(P->i_G > 0.0 && isfinite(P->i_G))) {
        *error = "gear ratio i_G must be > 0";
        return 1;
    }
    if (!(P->eps > 0.0 && isfinite(P->eps))) {
        *error = "tanh smoothing eps must be > 0 rad/s";
        return 1;
    }
    if (!(P->mode_tol >= 0.0 && P->omega_rest >= 0.0 && P->max_step > 0.0 && isfinite(P->max_step))) {
        *error = "mode_tol and omega_rest must be >= 0 and max_step > 0";
        return 1;
    }
    return 0;
}

double qomni_plant_substep(const QomniPlantParameters *P) {
    const double *p = P->p;
    double lam = (p[J_D_VL] + p[J_D_CL] / P->eps) / p[J_C_L];
    lam = fmax(lam, (p[J_D_VR] + p[J_D_CR] / P->eps) / p[J_C_R]);
    lam = fmax(lam, (p[J_D_VW] + p[J_D_CW] / P->eps) / p[J_B_W]);
    return lam > 0.0 ? fmin(P->max_step, 2.0 / lam) : P->max_step;
}

static void mode_alpha(int k, const double *g, double out[2]) {
    double t = k == 3 ? PI_2 : atan2(g[0], g[1]);
    out[0] = -t;
    out[1] = t;
}

static double icr_residual(Model *m, const double alpha[2]) {
    double a[2] = {alpha[0], alpha[1]}, f[2];
    double av = qomni_plant_alpha_v_from_alpha(a, m->g);
    if (!isfinite(av) || !(fabs(av) <= atan2(m->g[0], m->g[1]) + 1e-12)) return INFINITY;
    qomni_plant_f_icr(av, m->g, f);
    return fmax(fabs(alpha[0] - f[0]), fabs(alpha[1] - f[1]));
}

static double distance(const double a[2], const double b[2]) { return fmax(fabs(a[0] - b[0]), fabs(a[1] - b[1])); }

int qomni_plant_configuration_mode(const double alpha[2], const QomniPlantParameters *P) {
    Model m;
    model_of(P, &m);
    double m3[2], m4[2];
    mode_alpha(3, m.g, m3);
    mode_alpha(4, m.g, m4);
    if (distance(alpha, m3) <= P->mode_tol) return 3;
    if (distance(alpha, m4) <= P->mode_tol) return 4;
    if (icr_residual(&m, alpha) <= P->mode_tol) return 2;
    return 1;
}

static void set_alpha(Model *m, double *y, const double target[2]);
static void configuration(Model *m, int kc, const double alpha[2], double cfg[2], double *alpha_v);
static void engage(Model *m, double *y, int kc, const double cfg[2], double alpha_v);

int qomni_plant_init(double state[QOMNI_PLANT_N_STATE], const double pose0[3], const double alpha0[2],
                     const double velocity0[5], const QomniPlantParameters *P, const char **error) {
    if (qomni_plant_check(P, error)) return 1;
    for (int j = 0; j < 5; j++) {
        if (!isfinite(j < 3 ? pose0[j] : 0.0) || !isfinite(velocity0[j])) {
            *error = "the initial pose and velocities must be finite";
            return 1;
        }
    }
    for (int j = 0; j < 2; j++) {
        if (!(fabs(alpha0[j]) <= P->steering_limit)) {
            *error = "the initial steering angles alpha_l0, alpha_r0 must lie within the stops +-steering_limit";
            return 1;
        }
    }
    memset(state, 0, QOMNI_PLANT_N_STATE * sizeof state[0]);
    memcpy(&state[PS_X], pose0, 3 * sizeof pose0[0]);
    memcpy(&state[PS_ALPHA], alpha0, 2 * sizeof alpha0[0]);
    state[PS_SDOT] = velocity0[3];
    state[PS_SDOT + 1] = velocity0[4];
    state[PS_K] = 1.0;
    if (velocity0[0] == 0.0 && velocity0[1] == 0.0 && velocity0[2] == 0.0) return 0;
    Model m;
    model_of(P, &m);
    int kc = qomni_plant_configuration_mode(alpha0, P);
    if (kc == 1) {
        *error = "an initial chassis velocity needs alpha_l0, alpha_r0 within mode_tol of mode 2, 3 or 4's "
                 "configuration (9)";
        return 1;
    }
    double cfg[2], av;
    configuration(&m, kc, alpha0, cfg, &av);
    engage(&m, state, kc, cfg, av);
    state[PS_SDOT + chassis_column(kc)] = kc == 2 ? velocity0[0] : velocity0[kc == 3 ? 1 : 2];
    memset(&state[PS_BETA], 0, 4 * sizeof state[0]); /* beta(0) = 0 by definition */
    state[PS_K] = (double)kc;
    return 0;
}

/* dy/dt of the integrated state y in engaged mode k */
static void derivative(Model *m, int k, const double *y, const double u[4], double *dy) {
    double alpha[2] = {y[PS_ALPHA], y[PS_ALPHA + 1]}, sd[2] = {y[PS_SDOT], y[PS_SDOT + 1]};
    double uu[4] = {u[0], u[1], u[2], u[3]}, sdd[2] = {0.0, 0.0}, qd[9];
    double av = 0.0;
    if (k == 2) {
        av = y[PS_ALPHA_V];
        qomni_plant_f_icr(av, m->g, alpha);
    }
    switch (k) {
    case 1: qomni_plant_rhs_1(alpha, av, sd, uu, m->p, m->g, m->i_G, m->eps, sdd, qd); break;
    case 2: qomni_plant_rhs_2(alpha, av, sd, uu, m->p, m->g, m->i_G, m->eps, sdd, qd); break;
    case 3: qomni_plant_rhs_3(alpha, av, sd, uu, m->p, m->g, m->i_G, m->eps, sdd, qd); break;
    default: qomni_plant_rhs_4(alpha, av, sd, uu, m->p, m->g, m->i_G, m->eps, sdd, qd); break;
    }
    double c = cos(y[PS_GAMMA]), s = sin(y[PS_GAMMA]);
    dy[PS_X] = c * qd[0] - s * qd[1];
    dy[PS_Y] = s * qd[0] + c * qd[1];
    dy[PS_GAMMA] = qd[2];
    dy[PS_ALPHA] = qd[3];
    dy[PS_ALPHA + 1] = qd[4];
    dy[PS_ALPHA_V] = k == 2 ? sd[0] : 0.0;
    for (int i = 0; i < 4; i++) dy[PS_BETA + i] = qd[5 + i];
    dy[PS_SDOT] = sdd[0];
    dy[PS_SDOT + 1] = n_of(k) == 2 ? sdd[1] : 0.0;
}

static void rk4(Model *m, int k, double *y, const double u[4], double h) {
    double k1[N_Y], k2[N_Y], k3[N_Y], k4[N_Y], t[N_Y];
    derivative(m, k, y, u, k1);
    for (int j = 0; j < N_Y; j++) t[j] = y[j] + 0.5 * h * k1[j];
    derivative(m, k, t, u, k2);
    for (int j = 0; j < N_Y; j++) t[j] = y[j] + 0.5 * h * k2[j];
    derivative(m, k, t, u, k3);
    for (int j = 0; j < N_Y; j++) t[j] = y[j] + h * k3[j];
    derivative(m, k, t, u, k4);
    for (int j = 0; j < N_Y; j++) y[j] += h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]);
}

/* Move alpha to target and roll the wheels with it (beta += H_1,beta delta_alpha), so the rolling
 * constraints stay exact. */
static void set_alpha(Model *m, double *y, const double target[2]) {
    double H1[18], a[2] = {y[PS_ALPHA], y[PS_ALPHA + 1]};
    kinematic_model(m, 1, a, 0.0, H1);
    double d0 = target[0] - y[PS_ALPHA], d1 = target[1] - y[PS_ALPHA + 1];
    for (int i = 0; i < 4; i++) y[PS_BETA + i] += H1[(5 + i) * 2] * d0 + H1[(5 + i) * 2 + 1] * d1;
    y[PS_ALPHA] = target[0];
    y[PS_ALPHA + 1] = target[1];
}

/* Generalized drive force tau_c = h_c^T B u on the chassis column h_c of H_k, its static Coulomb level
 * F_c = d_cw sum |h_c,beta_i| and the largest |h_c,beta_i|. */
static void chassis_force(Model *m, int k, double alpha[2], double alpha_v, const double u[4], double *tau,
                          double *F, double *hmax) {
    double H[18];
    int n = n_of(k), c = chassis_column(k);
    kinematic_model(m, k, alpha, alpha_v, H);
    *tau = *F = *hmax = 0.0;
    for (int i = 0; i < 4; i++) {
        double h = H[(5 + i) * n + c];
        *tau += m->i_G * h * u[i];
        *F += m->p[J_D_CW] * fabs(h);
        *hmax = fmax(*hmax, fabs(h));
    }
}

/* mode 1 -> k at rest: the wheels sit in mode k's configuration (within mode_tol) and the drive force
 * breaks the chassis loose; in mode 3 no side may be pulled off its stop by more than its static
 * steering friction. */
static void configuration(Model *m, int kc, const double alpha[2], double cfg[2], double *alpha_v) {
    *alpha_v = 0.0;
    if (kc == 2) {
        double a[2] = {alpha[0], alpha[1]};
        *alpha_v = qomni_plant_alpha_v_from_alpha(a, m->g);
        qomni_plant_f_icr(*alpha_v, m->g, cfg);
    } else {
        mode_alpha(kc, m->g, cfg);
    }
}

/* set alpha onto mode kc's configuration cfg and project the steering rate onto the mode */
static void engage(Model *m, double *y, int kc, const double cfg[2], double alpha_v) {
    double alpha_dot[2] = {y[PS_SDOT], y[PS_SDOT + 1]};
    set_alpha(m, y, cfg);
    if (kc == 2) {
        double H2[18], c[2] = {cfg[0], cfg[1]};
        kinematic_model(m, 2, c, alpha_v, H2);
        double f0 = H2[3 * 2], f1 = H2[4 * 2]; /* f_ICR'(alpha_v) */
        y[PS_ALPHA_V] = alpha_v;
        y[PS_SDOT] = (f0 * alpha_dot[0] + f1 * alpha_dot[1]) / (f0 * f0 + f1 * f1);
    } else {
        y[PS_ALPHA_V] = 0.0;
        y[PS_SDOT] = 0.0;
    }
    y[PS_SDOT + 1] = 0.0;
}

static void try_engage(Model *m, double *y, int *k, const double u[4]) {
    double alpha[2] = {y[PS_ALPHA], y[PS_ALPHA + 1]}, cfg[2], av;
    int kc = qomni_plant_configuration_mode(alpha, m->P);
    if (kc == 1) return;
    configuration(m, kc, alpha, cfg, &av);
    double tau, F, hmax;
    chassis_force(m, kc, cfg, av, u, &tau, &F, &hmax);
    if (!(fabs(tau) > F)) return;
    if (kc == 3) {
        double H1[18];
        kinematic_model(m, 1, cfg, 0.0, H1);
        for (int j = 0; j < 2; j++) {
            double tau_s = 0.0, F_s = m->p[j == 0 ? J_D_CL : J_D_CR];
            for (int i = 0; i < 4; i++) {
                tau_s += m->i_G * H1[(5 + i) * 2 + j] * u[i];
                F_s += m->p[J_D_CW] * fabs(H1[(5 + i) * 2 + j]);
            }
            double into_stop = cfg[j] > 0.0 ? 1.0 : -1.0;
            if (into_stop * tau_s < -F_s) return; /* this side leaves its stop: it steers (mode 1) */
        }
    }
    engage(m, y, kc, cfg, av);
    *k = kc;
}

/* mode k -> 1: the chassis rate is below omega_rest (wheel side) or crossed zero since the start of the
 * sub-step (rate v_start) while the drive force does not exceed the static Coulomb level. */
static bool rest_due(Model *m, const double *y, int k, const double u[4], double v_start) {
    double alpha[2] = {y[PS_ALPHA], y[PS_ALPHA + 1]}, av = k == 2 ? y[PS_ALPHA_V] : 0.0;
    double tau, F, hmax;
    chassis_force(m, k, alpha, av, u, &tau, &F, &hmax);
    double v = y[PS_SDOT + chassis_column(k)];
    bool slow = hmax * fabs(v) < m->P->omega_rest || v * v_start < 0.0;
    return slow && fabs(tau) <= F;
}

static void come_to_rest(Model *m, double *y, int *k) {
    if (*k == 2) {
        double H2[18], alpha[2] = {y[PS_ALPHA], y[PS_ALPHA + 1]};
        kinematic_model(m, 2, alpha, y[PS_ALPHA_V], H2);
        double rate = y[PS_SDOT];
        y[PS_SDOT] = H2[3 * 2] * rate;
        y[PS_SDOT + 1] = H2[4 * 2] * rate;
    } else {
        y[PS_SDOT] = y[PS_SDOT + 1] = 0.0;
    }
    y[PS_ALPHA_V] = 0.0;
    *k = 1;
}

/* Apply the transition due at y (engaging from rest, coming to rest); returns whether k changed. */
static bool transition(Model *m, double *y, int *k, const double u[4], double v_start) {
    int before = *k;
    if (*k == 1) try_engage(m, y, k, u);
    else if (rest_due(m, y, *k, u, v_start)) come_to_rest(m, y, k);
    return *k != before;
}

/* the stops: alpha within +-steering_limit, the outward rate absorbed (mode 1); alpha_v within
 * +-arctan(l/b) (mode 2, where the inner wheel reaches its stop). Returns whether a stop was reached that
 * start (the state at the start of the sub-step) was not at. */
static bool stops(Model *m, double *y, int k, const double *start) {
    bool reached = false;
    if (k == 1) {
        double lim = m->P->steering_limit, target[2] = {y[PS_ALPHA], y[PS_ALPHA + 1]};
        bool hit = false;
        for (int j = 0; j < 2; j++) {
            if (fabs(target[j]) > lim) {
                target[j] = copysign(lim, target[j]);
                if (y[PS_SDOT + j] * target[j] > 0.0) y[PS_SDOT + j] = 0.0;
                hit = true;
                reached = reached || fabs(start[PS_ALPHA + j]) < lim;
            }
        }
        if (hit) set_alpha(m, y, target);
    } else if (k == 2) {
        double av_max = atan2(m->g[0], m->g[1]);
        if (fabs(y[PS_ALPHA_V]) > av_max) {
            reached = fabs(start[PS_ALPHA_V]) < av_max;
            y[PS_ALPHA_V] = copysign(av_max, y[PS_ALPHA_V]);
            if (y[PS_SDOT] * y[PS_ALPHA_V] > 0.0) y[PS_SDOT] = 0.0;
        }
        double a[2];
        qomni_plant_f_icr(y[PS_ALPHA_V], m->g, a);
        y[PS_ALPHA] = a[0];
        y[PS_ALPHA + 1] = a[1];
    }
    return reached;
}

/* y_out = y advanced by theta in mode k with the stops applied; returns whether an event lies within
 * theta: a stop reached, or a transition due at y_out (which is not applied). */
static bool advance(Model *m, int k, const double *y, const double u[4], double theta, double *y_out) {
    memcpy(y_out, y, N_Y * sizeof y[0]);
    rk4(m, k, y_out, u, theta);
    bool event = stops(m, y_out, k, y);
    double trial[N_Y];
    int kk = k;
    memcpy(trial, y_out, sizeof trial);
    return transition(m, trial, &kk, u, y[PS_SDOT + chassis_column(k)]) || event;
}

#define MAX_EVENTS 8 /* events resolved within one sub-step; later ones are taken at its end */
#define EVENT_RESOLUTION 0x1p-50 /* bisection down to 2^-50 of the remaining sub-step (about 2e-19 s) */

/* One sub-step dt in mode *k: a transition due at the start is taken there; an event within the sub-step
 * (a stop reached, a transition due) is located by bisection to within 2^-50 of the sub-step and taken
 * there; the rest of the sub-step is integrated from there, so the switching times do not depend on the
 * sub-step grid (and thus not on the communication step). */
static void substep(Model *m, double *y, int *k, const double u[4], double dt) {
    transition(m, y, k, u, y[PS_SDOT + chassis_column(*k)]);
    double rest = dt, next[N_Y];
    for (int e = 0; rest > 0.0; e++) {
        double v_start = y[PS_SDOT + chassis_column(*k)];
        if (!advance(m, *k, y, u, rest, next) || e >= MAX_EVENTS) {
            memcpy(y, next, sizeof next);
            transition(m, y, k, u, v_start);
            return;
        }
        double lo = 0.0, hi = rest;
        while (hi - lo > EVENT_RESOLUTION * rest) {
            double mid = lo + 0.5 * (hi - lo);
            if (advance(m, *k, y, u, mid, next)) hi = mid;
            else lo = mid;
        }
        advance(m, *k, y, u, hi, next);
        memcpy(y, next, sizeof next);
        transition(m, y, k, u, v_start);
        rest -= hi;
    }
}

int qomni_plant_step(double state[QOMNI_PLANT_N_STATE], const double u[4], const QomniPlantParameters *P,
                     double h, const char **error) {
    if (qomni_plant_check(P, error)) return 1;
    for (int i = 0; i < 4; i++) {
        if (!isfinite(u[i])) {
            *error = "the motor torques must be finite";
            return 1;
        }
    }
    if (!(h > 0.0) || !isfinite(h)) {
        *error = "the step size must be > 0 and finite";
        return 1;
    }
    int k = (int)state[PS_K];
    if (k < 1 || k > 4) {
        *error = "corrupt state: engaged mode not in 1..4";
        return 1;
    }
    Model m;
    model_of(P, &m);
    double hs = qomni_plant_substep(P);
    double n = ceil(h / hs - 1e-9);
    if (n < 1.0) n = 1.0;
    double dt = h / n, y[N_Y];
    memcpy(y, state, sizeof y);
    for (double i = 0.0; i < n; i += 1.0) substep(&m, y, &k, u, dt);
    for (int j = 0; j < N_Y; j++) {
        if (!isfinite(y[j])) {
            *error = "the state became non-finite (check parameters and torques)";
            return 1;
        }
    }
    memcpy(state, y, sizeof y);
    state[PS_K] = (double)k;
    return 0;
}

void qomni_plant_outputs(const double state[QOMNI_PLANT_N_STATE], const QomniPlantParameters *P,
                         QomniPlantOutputs *out) {
    Model m;
    model_of(P, &m);
    int k = (int)state[PS_K];
    if (k < 1 || k > 4) k = 1;
    double alpha[2] = {state[PS_ALPHA], state[PS_ALPHA + 1]}, H[18];
    kinematic_model(&m, k, alpha, k == 2 ? state[PS_ALPHA_V] : 0.0, H);
    int n = n_of(k);
    for (int i = 0; i < 9; i++) {
        out->q_dot[i] = H[i * n] * state[PS_SDOT];
        if (n == 2) out->q_dot[i] += H[i * n + 1] * state[PS_SDOT + 1];
    }
    for (int i = 0; i < 4; i++) {
        out->motor_position[i] = P->i_G * state[PS_BETA + i];
        out->motor_velocity[i] = P->i_G * out->q_dot[5 + i];
    }
    out->k = k;
    out->k_configuration = qomni_plant_configuration_mode(alpha, P);
}
