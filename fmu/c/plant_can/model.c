/* model.c -- the plant-can FMU model: the hybrid plant (plant.h) driven by the torques its CiA 402 drives
 * apply (canopen_nodes.c), which the importer commands through CAN frames (lsbus_can.c). The storage
 * indices PL_* come from the generated config.h. The plant and its outputs are those of the plant FMU;
 * its motor_torque.* are outputs here (the torques applied, N m motor side). */
#include <stdio.h>
#include <string.h>

#include "plant_can.h"
#include "plant_fmu.h"

void plant_can_drive_data(const FmuValues *v, CanDriveData *d) {
    d->rated_torque = v->float64[PL_RATED_TORQUE];
    d->cycle_time = v->float64[PL_CYCLE_TIME];
    d->sync_timeout = v->float64[PL_SYNC_TIMEOUT];
    d->max_torque = v->int32[PL_MAX_TORQUE];
    d->torque_slope = v->int32[PL_MAX_TORQUE + 1];
    d->encoder_increments = v->int32[PL_MAX_TORQUE + 2];
    d->steering_sensor_bits = v->int32[PL_MAX_TORQUE + 3];
}

static int check_drive_data(const FmuValues *v, char *message, size_t size) {
    CanDriveData d;
    plant_can_drive_data(v, &d);
    if (!(d.rated_torque > 0.0) || !(d.cycle_time > 0.0) || !(d.sync_timeout >= 0.0) || d.max_torque <= 0 ||
        d.max_torque > 32767 || d.torque_slope <= 0 || d.encoder_increments <= 0 || d.steering_sensor_bits < 1 ||
        d.steering_sensor_bits > 32) {
        snprintf(message, size, "drive data out of range: rated_torque %g N m, cycle_time %g s, sync_timeout %g s "
                 "(> 0, > 0, >= 0), max_torque %d (1..32767 per mille), torque_slope %d (> 0), "
                 "encoder_increments %d (> 0), steering_sensor_bits %d (1..32)", d.rated_torque, d.cycle_time,
                 d.sync_timeout, (int)d.max_torque, (int)d.torque_slope, (int)d.encoder_increments,
                 (int)d.steering_sensor_bits);
        return -1;
    }
    return 0;
}

FmuStatus fmu_model_initialize(FmuValues *v, char *message, size_t size) {
    if (check_drive_data(v, message, size)) return FMU_ERROR;
    return plant_fmu_initialize(v, message, size);
}

/* The drive data are fixed parameters: checked with the initial state, before the first step. */
FmuStatus fmu_model_do_step(FmuValues *v, double h, char *message, size_t size) {
    if (can_nodes_supervise(v, message, size)) return FMU_ERROR;
    QomniPlantParameters P;
    plant_fmu_parameters(v, &P);
    double u[4];
    can_nodes_applied_torque(v, u);
    const char *error = NULL;
    if (qomni_plant_step(v->state, u, &P, h, &error) != 0) {
        snprintf(message, size, "plant: %s", error ? error : "failed");
        return FMU_ERROR;
    }
    return FMU_OK;
}

FmuStatus fmu_model_calculate(FmuValues *v, char *message, size_t size) {
    if (plant_fmu_outputs(v, message, size) != FMU_OK) return FMU_ERROR;
    can_nodes_applied_torque(v, &v->float64[PL_MOTOR_TORQUE]);
    return FMU_OK;
}

int plant_can_sensors(FmuValues *v, double motor_position[4], double motor_velocity[4], double alpha[2]) {
    char message[FMU_MESSAGE_SIZE];
    if (fmu_model_calculate(v, message, sizeof message) != FMU_OK) return -1;
    memcpy(motor_position, &v->float64[PL_MOTOR_POSITION], 4 * sizeof(double));
    memcpy(motor_velocity, &v->float64[PL_MOTOR_VELOCITY], 4 * sizeof(double));
    memcpy(alpha, &v->float64[PL_ALPHA], 2 * sizeof(double));
    return 0;
}

/* Float64 inputs: none (the torques come through the bus). */
FmuStatus fmu_model_jacobian(FmuValues *v, double *J, char *message, size_t size) {
    (void)v, (void)J, (void)message, (void)size;
    return FMU_OK;
}
