/* model.c -- the plant FMU model: glue between the generic FMU core (fmu_instance.h) and the hybrid
 * plant (plant.h) through plant_fmu.h; the motor torques are the inputs PL_MOTOR_TORQUE. */
#include <stdio.h>

#include "plant_fmu.h"

FmuStatus fmu_model_initialize(FmuValues *v, char *message, size_t size) {
    return plant_fmu_initialize(v, message, size);
}

FmuStatus fmu_model_do_step(FmuValues *v, double h, char *message, size_t size) {
    QomniPlantParameters P;
    plant_fmu_parameters(v, &P);
    const char *error = NULL;
    if (qomni_plant_step(v->state, &v->float64[PL_MOTOR_TORQUE], &P, h, &error) != 0) {
        snprintf(message, size, "plant: %s", error ? error : "failed");
        return FMU_ERROR;
    }
    return FMU_OK;
}

FmuStatus fmu_model_calculate(FmuValues *v, char *message, size_t size) {
    return plant_fmu_outputs(v, message, size);
}

/* No output depends directly on an input (the torques act through the state over a step): the Jacobian
 * of the outputs by the inputs is 0, exactly. */
FmuStatus fmu_model_jacobian(FmuValues *v, double *J, char *message, size_t size) {
    (void)v, (void)message, (void)size;
    for (size_t j = 0; j < (size_t)N_FLOAT64 * N_FLOAT64; j++) J[j] = 0.0;
    return FMU_OK;
}
