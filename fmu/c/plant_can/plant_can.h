/* plant_can.h -- the parts of the plant-can FMU: the plant glue (model.c), the vehicle's CANopen nodes
 * (canopen_nodes.c) and the FMI-LS-BUS CAN transport (lsbus_can.c). The bus state is FmuBusState
 * (bus_state.h) inside FmuValues. */
#ifndef QOMNI_PLANT_CAN_H
#define QOMNI_PLANT_CAN_H

#include <stddef.h>
#include <stdint.h>

#include "fmu_instance.h"

/* The drives' and encoders' data (FMU parameters; the data sheet's values by default). */
typedef struct {
    double rated_torque;          /* N m motor side, 0x6076 / 1000 */
    double cycle_time;            /* s, communication cycle period 0x1006 (the quick stop ramp's period) */
    double sync_timeout;          /* s, SYNC loss time of the nodes; 0 = no supervision */
    int32_t max_torque;           /* per mille of 0x6076, 0x6072 */
    int32_t torque_slope;         /* per mille / s, 0x6087 (quick stop ramp) */
    int32_t encoder_increments;   /* motor encoder increments per motor revolution */
    int32_t steering_sensor_bits; /* resolution of the absolute steering sensors (0x6004 units) */
} CanDriveData;

/* Little-endian fields of CAN data and bus operations. */
static inline void can_put16(uint8_t *p, uint32_t x) { p[0] = (uint8_t)x, p[1] = (uint8_t)(x >> 8); }
static inline void can_put32(uint8_t *p, uint32_t x) { can_put16(p, x), can_put16(p + 2, x >> 16); }
static inline uint32_t can_get32(const uint8_t *p) {
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

/* model.c: the drive data of v; the sensors' physical values at v's time (motor side rad, rad/s; rad). */
void plant_can_drive_data(const FmuValues *v, CanDriveData *d);
int plant_can_sensors(FmuValues *v, double motor_position[4], double motor_velocity[4], double alpha[2]);

/* lsbus_can.c: queue one classic CAN data frame (11-bit id, len <= 8) as a CAN Transmit operation in
 * Tx_Data; 0, or -1 when Tx_Data is full (the importer does not read it). */
int can_transmit(FmuBusState *b, uint32_t id, const uint8_t *data, uint8_t len);

/* canopen_nodes.c: each returns 0, or -1 with a message in error (at most size bytes).
 *   can_nodes_boot: power on: every node boots into PRE-OPERATIONAL and sends its boot-up message;
 *   can_nodes_receive: one received CAN data frame;
 *   can_nodes_supervise: before a step: SYNC loss (no SYNC for sync_timeout in OPERATIONAL) ->
 *     EMCY 0x8100 and the drives' abort connection reaction (0x6007 = 1: FAULT, torque off). */
int can_nodes_boot(FmuValues *v, char *error, size_t size);
int can_nodes_receive(FmuValues *v, uint32_t id, const uint8_t *data, uint8_t len, char *error, size_t size);
int can_nodes_supervise(FmuValues *v, char *error, size_t size);
/* The torques the drives apply now, N m motor side (0 unless OPERATION ENABLED or QUICK STOP ACTIVE). */
void can_nodes_applied_torque(const FmuValues *v, double u[4]);

#endif /* QOMNI_PLANT_CAN_H */
