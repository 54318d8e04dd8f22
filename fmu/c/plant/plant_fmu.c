/* plant_fmu.c -- see plant_fmu.h. */
#include "plant_fmu.h"

#include <stdio.h>
#include <string.h>

#if N_STATES != QOMNI_PLANT_N_STATE
#error "config.h N_STATES must equal QOMNI_PLANT_N_STATE"
#endif

void plant_fmu_parameters(const FmuValues *v, QomniPlantParameters *P) {
    const double *x = v->float64;
    memcpy(P->p, &x[PL_P], sizeof P->p);
    memcpy(P->geometry, &x[PL_GEOMETRY], sizeof P->geometry);
    P->steering_limit = x[PL_STEERING_LIMIT];
    P->i_G = x[PL_I_G];
    P->eps = x[PL_EPS];
    P->mode_tol = x[PL_MODE_TOL];
    P->omega_rest = x[PL_OMEGA_REST];
    P->max_step = x[PL_MAX_STEP];
}

FmuStatus plant_fmu_initialize(FmuValues *v, char *message, size_t size) {
    QomniPlantParameters P;
    plant_fmu_parameters(v, &P);
    const char *error = NULL;
    const double *x = v->float64;
    double pose0[3] = {x[PL_INITIAL], x[PL_INITIAL + 1], x[PL_INITIAL + 2]};
    double alpha0[2] = {x[PL_INITIAL + 3], x[PL_INITIAL + 4]};
    double velocity0[5] = {x[PL_INITIAL + 5], x[PL_INITIAL + 6], x[PL_INITIAL + 7], x[PL_INITIAL + 8],
                           x[PL_INITIAL + 9]};
    if (qomni_plant_init(v->state, pose0, alpha0, velocity0, &P, &error) != 0) {
        snprintf(message, size, "%s", error ? error : "invalid initial state");
        return FMU_ERROR;
    }
    return FMU_OK;
}

FmuStatus plant_fmu_outputs(FmuValues *v, char *message, size_t size) {
    QomniPlantParameters P;
    plant_fmu_parameters(v, &P);
    const char *error = NULL;
    if (qomni_plant_check(&P, &error) != 0) {
        snprintf(message, size, "plant: %s", error);
        return FMU_ERROR;
    }
    QomniPlantOutputs out;
    qomni_plant_outputs(v->state, &P, &out);
    double *y = v->float64;
    y[PL_POSE] = v->state[PS_X];
    y[PL_POSE + 1] = v->state[PS_Y];
    y[PL_POSE + 2] = v->state[PS_GAMMA];
    for (int j = 0; j < 3; j++) y[PL_VELOCITY + j] = out.q_dot[j];
    y[PL_ALPHA] = v->state[PS_ALPHA];
    y[PL_ALPHA + 1] = v->state[PS_ALPHA + 1];
    y[PL_ALPHA_DOT] = out.q_dot[3];
    y[PL_ALPHA_DOT + 1] = out.q_dot[4];
    for (int i = 0; i < 4; i++) {
        y[PL_MOTOR_POSITION + i] = out.motor_position[i];
        y[PL_MOTOR_VELOCITY + i] = out.motor_velocity[i];
    }
    v->int32[PL_K] = out.k;
    v->int32[PL_K_CONFIGURATION] = out.k_configuration;
    return FMU_OK;
}
