/* model.c -- the feed-forward FMU model: glue between the generic FMU core (fmu_instance.h) and the
 * feed-forward law (feedforward.h). The storage indices FF_* come from the generated config.h. */
#include <stdio.h>

#include "feedforward.h"
#include "fmu_instance.h"

/* Every real input is finite here: the core refuses a non-finite input when it is set (fmu_instance.h),
 * whether the mode k reads it or not. */
FmuStatus fmu_model_calculate(FmuValues *v, char *message, size_t size) {
    const double *x = v->float64;
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

FmuStatus fmu_model_jacobian(FmuValues *v, double *J, char *message, size_t size) {
    const double *x = v->float64;
    double q_alpha[2] = {x[FF_Q + 3], x[FF_Q + 4]}, D[4 * QOMNI_FF_N_KNOWNS];
    const char *error = NULL;
    int k = (int)v->int32[FF_K];
    if (qomni_feedforward_jacobian(k, q_alpha, x[FF_ALPHA_V], v->boolean[FF_USE_ALPHA_V_INPUT], &x[FF_S_DOT],
                                   &x[FF_S_DDOT], &x[FF_P], &x[FF_GEOMETRY], x[FF_I_G], x[FF_EPS], D, &error) != 0) {
        snprintf(message, size, "derivative of the feed-forward (21) with k = %d: %s", k, error ? error : "failed");
        return FMU_ERROR;
    }
    /* the knowns' storage indices, in the order of qomni_feedforward_jacobian */
    const size_t known[QOMNI_FF_N_KNOWNS] = {FF_Q + 3, FF_Q + 4, FF_ALPHA_V, FF_S_DOT, FF_S_DOT + 1, FF_S_DDOT,
                                             FF_S_DDOT + 1};
    for (int i = 0; i < 4; i++) {
        for (size_t j = 0; j < N_FLOAT64; j++) J[(FF_MOTOR_TORQUE + i) * N_FLOAT64 + j] = 0.0;
        for (int c = 0; c < QOMNI_FF_N_KNOWNS; c++)
            J[(FF_MOTOR_TORQUE + i) * N_FLOAT64 + known[c]] = D[i * QOMNI_FF_N_KNOWNS + c];
    }
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
