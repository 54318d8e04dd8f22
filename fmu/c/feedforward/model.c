/* model.c -- the feed-forward FMU model: glue between the generic FMU core (fmu_instance.h) and the
 * feed-forward law (feedforward.h). The storage indices FF_* come from the generated config.h. */
#include <math.h>
#include <stdio.h>

#include "feedforward.h"
#include "fmu_instance.h"

/* Every real input must be finite, whether the mode k uses it or not: a NaN is an error, never a
 * silently ignored value (modes 3 and 4 fix the steering angles and would not read q.alpha_*). */
static int check_inputs(const double *x, char *message, size_t size) {
    static const char *q_names[9] = {"q.x_ch", "q.y_ch", "q.gamma_ch", "q.alpha_l", "q.alpha_r",
                                     "q.beta_fl", "q.beta_rl", "q.beta_fr", "q.beta_rr"};
    for (int j = 0; j < 9; j++)
        if (!isfinite(x[FF_Q + j])) {
            snprintf(message, size, "input %s is not finite (%g)", q_names[j], x[FF_Q + j]);
            return -1;
        }
    for (int j = 0; j < 2; j++) {
        if (!isfinite(x[FF_S_DOT + j])) {
            snprintf(message, size, "input s_dot[%d] is not finite (%g)", j + 1, x[FF_S_DOT + j]);
            return -1;
        }
        if (!isfinite(x[FF_S_DDOT + j])) {
            snprintf(message, size, "input s_ddot[%d] is not finite (%g)", j + 1, x[FF_S_DDOT + j]);
            return -1;
        }
    }
    if (!isfinite(x[FF_ALPHA_V])) {
        snprintf(message, size, "input alpha_v is not finite (%g)", x[FF_ALPHA_V]);
        return -1;
    }
    return 0;
}

FmuStatus fmu_model_calculate(FmuValues *v, char *message, size_t size) {
    const double *x = v->float64;
    if (check_inputs(x, message, size) != 0) return FMU_ERROR;
    double q_alpha[2] = {x[FF_Q + 3], x[FF_Q + 4]}; /* q = (x_ch, y_ch, gamma_ch, alpha_l, alpha_r, beta...) */
    const char *error = NULL;
    double u[4];
    int k = (int)v->int32[FF_K];
    if (qomni_feedforward(k, q_alpha, x[FF_ALPHA_V], v->boolean[FF_USE_ALPHA_V_INPUT], &x[FF_S_DOT],
                          &x[FF_S_DDOT], &x[FF_P], &x[FF_GEOMETRY], x[FF_I_G], x[FF_EPS], u, &error) != 0) {
        snprintf(message, size, "feed-forward (21) with k = %d: %s", k, error ? error : "failed");
        return FMU_ERROR;
    }
    for (int j = 0; j < 4; j++) v->float64[FF_MOTOR_TORQUE + j] = u[j];
    return FMU_OK;
}

/* The feed-forward law is algebraic: no internal state. */
FmuStatus fmu_model_initialize(FmuValues *v, char *message, size_t size) {
    (void)v, (void)message, (void)size;
    return FMU_OK;
}

FmuStatus fmu_model_do_step(FmuValues *v, double h, char *message, size_t size) {
    (void)v, (void)h, (void)message, (void)size;
    return FMU_OK;
}
