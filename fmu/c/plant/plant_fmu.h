/* plant_fmu.h -- the plant's glue to the generic FMU core, shared by the models built on the plant (plant,
 * plant-can): parameters, initial state and outputs from the storage indices PL_* of config.h. */
#ifndef QOMNI_PLANT_FMU_H
#define QOMNI_PLANT_FMU_H

#include <stddef.h>

#include "fmu_instance.h"
#include "plant.h"

/* The plant's parameters from v (p, geometry, steering_limit, i_G, eps, mode_tol, omega_rest, max_step). */
void plant_fmu_parameters(const FmuValues *v, QomniPlantParameters *P);
/* v->state from the initial-state parameters x0 ... alpha_r_dot0 (fmu_model_initialize of the plant). */
FmuStatus plant_fmu_initialize(FmuValues *v, char *message, size_t size);
/* The plant's Float64 outputs (pose, velocities, steering, encoders) and k, k_configuration from v->state. */
FmuStatus plant_fmu_outputs(FmuValues *v, char *message, size_t size);

#endif /* QOMNI_PLANT_FMU_H */
