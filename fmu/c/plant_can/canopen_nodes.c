/* canopen_nodes.c -- the vehicle's CANopen nodes in the plant-can FMU, PDO path in lock-step: the same
 * behaviour as the emulator's nodes (hil/device/server.py, drive402.py, node301.py) for NMT, SYNC, the
 * RPDOs and the TPDOs, so a master exercising the PDO path sees the same frames.
 *
 * NMT (CiA 301 section 7.2.8): boot-up into PRE-OPERATIONAL; start, stop, enter pre-operational, reset
 * node (the drive's application too: SWITCH ON DISABLED, set-points 0), reset communication; PDOs only in
 * OPERATIONAL. Leaving OPERATIONAL while OPERATION ENABLED is a connection loss (0x6007 = 1: FAULT).
 * SYNC (section 7.2.5): in this order (hil/device/server.py, lock-step) -- 1. every OPERATIONAL node
 * applies the RPDOs received since the last SYNC (the controlword takes effect here); 2. every drive
 * latches its torque for the coming cycle: OPERATION ENABLED: clip(0x6071, +-0x6072) (cyclic synchronous
 * torque, 0x6061 = 10), QUICK STOP ACTIVE: the ramp to 0 at 0x6087 per cycle, else 0; 3. the sensors are
 * sampled at the SYNC instant; 4. every OPERATIONAL node sends its TPDOs (drives 1..4, TPDO1 then TPDO2;
 * encoders 5, 6). A SYNC longer than 1 byte is ignored.
 * CiA 402-2 section 6: the power state machine of controlword commands (drive402.py's transition table,
 * quick stop option 0x605A = 2: ramp, then SWITCH ON DISABLED), statusword = state coding | remote (bit 9)
 * | voltage enabled (bit 4) | quick stop (bit 5 in SWITCH ON DISABLED) | drive follows the command
 * (bit 12, OPERATION ENABLED) | internal limit (bit 11, target clipped).
 * Sensors: 0x6064 = floor(i_G beta / 2 pi * increments) wrapped to INTEGER32 (an incremental encoder
 * counts whole increments), 0x606C = rint(i_G beta_dot / 2 pi * increments) saturated, 0x6077 = the
 * applied torque (per mille), 0x6004 = rint(alpha / 2 pi * 2^bits) mod 2^bits.
 * Not here: SDO (the drives are configured by the FMU's parameters and always in cyclic synchronous
 * torque), heartbeat, LSS, the other modes of operation, PDO re-mapping. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "plant_can.h"

#define TWO_PI 6.283185307179586

#define NMT_PRE_OPERATIONAL 0x7F
#define NMT_OPERATIONAL 0x05
#define NMT_STOPPED 0x04

/* CiA 402 power states (statusword state coding) */
#define ST_SWITCH_ON_DISABLED 0x0040
#define ST_READY_TO_SWITCH_ON 0x0021
#define ST_SWITCHED_ON 0x0023
#define ST_OPERATION_ENABLED 0x0027
#define ST_QUICK_STOP_ACTIVE 0x0007
#define ST_FAULT 0x0008

#define SW_VOLTAGE_ENABLED 0x0010
#define SW_QUICK_STOP 0x0020
#define SW_REMOTE 0x0200
#define SW_INTERNAL_LIMIT 0x0800
#define SW_FOLLOWS_COMMAND 0x1000
#define CW_FAULT_RESET 0x0080

#define EMCY_COMMUNICATION 0x8100
#define ERROR_REGISTER_COMMUNICATION 0x11 /* generic + communication bits of 0x1001 */

enum { CMD_SHUTDOWN, CMD_SWITCH_ON, CMD_ENABLE_OPERATION, CMD_DISABLE_VOLTAGE, CMD_QUICK_STOP, CMD_FAULT_RESET };

static int decode_controlword(uint16_t cw) {
    if (cw & CW_FAULT_RESET) return CMD_FAULT_RESET;
    if (!(cw & 0x02)) return CMD_DISABLE_VOLTAGE;
    if (!(cw & 0x04)) return CMD_QUICK_STOP;
    if (!(cw & 0x01)) return CMD_SHUTDOWN;
    if (!(cw & 0x08)) return CMD_SWITCH_ON;
    return CMD_ENABLE_OPERATION;
}

/* Transition table of CiA 402-2 section 6 (drive402.py _TRANSITIONS); 0: no transition. */
static uint16_t transition(uint16_t state, int command) {
    switch (state) {
    case ST_SWITCH_ON_DISABLED:
        return command == CMD_SHUTDOWN ? ST_READY_TO_SWITCH_ON : 0;                        /* 2 */
    case ST_READY_TO_SWITCH_ON:
        if (command == CMD_SWITCH_ON) return ST_SWITCHED_ON;                               /* 3 */
        if (command == CMD_ENABLE_OPERATION) return ST_OPERATION_ENABLED;                  /* 3 + 4 */
        if (command == CMD_DISABLE_VOLTAGE || command == CMD_QUICK_STOP) return ST_SWITCH_ON_DISABLED; /* 7 */
        return 0;
    case ST_SWITCHED_ON:
        if (command == CMD_ENABLE_OPERATION) return ST_OPERATION_ENABLED;                  /* 4 */
        if (command == CMD_SHUTDOWN) return ST_READY_TO_SWITCH_ON;                         /* 6 */
        if (command == CMD_DISABLE_VOLTAGE || command == CMD_QUICK_STOP) return ST_SWITCH_ON_DISABLED; /* 10 */
        return 0;
    case ST_OPERATION_ENABLED:
        if (command == CMD_SWITCH_ON) return ST_SWITCHED_ON;                               /* 5 */
        if (command == CMD_SHUTDOWN) return ST_READY_TO_SWITCH_ON;                         /* 8 */
        if (command == CMD_DISABLE_VOLTAGE) return ST_SWITCH_ON_DISABLED;                  /* 9 */
        if (command == CMD_QUICK_STOP) return ST_QUICK_STOP_ACTIVE;                        /* 11 */
        return 0;
    case ST_QUICK_STOP_ACTIVE:
        return command == CMD_DISABLE_VOLTAGE ? ST_SWITCH_ON_DISABLED : 0;                 /* 12 */
    default:
        return 0;
    }
}

static bool voltage_on(uint16_t state) {
    return state == ST_READY_TO_SWITCH_ON || state == ST_SWITCHED_ON || state == ST_OPERATION_ENABLED ||
           state == ST_QUICK_STOP_ACTIVE;
}

static void update_statusword(CanDrive *d) {
    uint16_t word = d->state | SW_REMOTE;
    if (voltage_on(d->state)) word |= SW_VOLTAGE_ENABLED;
    if (d->state == ST_SWITCH_ON_DISABLED) word |= SW_QUICK_STOP;
    if (d->state == ST_OPERATION_ENABLED) {
        word |= SW_FOLLOWS_COMMAND;
        if (d->limited) word |= SW_INTERNAL_LIMIT;
    }
    d->statusword = word;
}

static void set_state(CanDrive *d, uint16_t state) {
    d->state = state;
    if (state != ST_OPERATION_ENABLED) {
        d->applied_torque = 0;
        d->limited = false;
    }
    update_statusword(d);
}

static void reset_application(CanDrive *d) {
    memset(d, 0, sizeof *d);
    set_state(d, ST_SWITCH_ON_DISABLED); /* transitions 0 and 1, automatic */
}

static void apply_controlword(CanDrive *d, uint16_t cw) {
    int command = decode_controlword(cw);
    bool rising = (cw & CW_FAULT_RESET) && !(d->controlword & CW_FAULT_RESET);
    d->controlword = cw;
    if (command == CMD_FAULT_RESET) {
        if (d->state == ST_FAULT && rising) set_state(d, ST_SWITCH_ON_DISABLED);         /* 15 */
        return;
    }
    uint16_t next = transition(d->state, command);
    if (next == ST_QUICK_STOP_ACTIVE) {
        int32_t torque = d->applied_torque; /* the ramp starts from the torque applied now */
        set_state(d, ST_QUICK_STOP_ACTIVE);
        d->applied_torque = torque;
    } else if (next) {
        set_state(d, next);
    }
}

static void fault(CanDrive *d) {
    if (d->state != ST_FAULT) set_state(d, ST_FAULT); /* 13 + 14: torque off */
}

static void latch_torque(CanDrive *d, const CanDriveData *data) {
    bool limited = false;
    int32_t torque = 0;
    if (d->state == ST_OPERATION_ENABLED) {
        int32_t target = d->target_torque, limit = data->max_torque;
        torque = target < -limit ? -limit : target > limit ? limit : target;
        limited = torque != target;
    } else if (d->state == ST_QUICK_STOP_ACTIVE) {
        int32_t step = (int32_t)(data->torque_slope * data->cycle_time);
        if (step < 1) step = 1;
        torque = d->applied_torque;
        torque = (torque <= step && torque >= -step) ? 0 : torque > 0 ? torque - step : torque + step;
        if (torque == 0) set_state(d, ST_SWITCH_ON_DISABLED); /* 0x605A = 2: then transition 12 */
    }
    d->applied_torque = torque;
    if (limited != d->limited) {
        d->limited = limited;
        update_statusword(d);
    }
}

static int send(FmuValues *v, uint32_t id, const uint8_t *data, uint8_t len, char *error, size_t size) {
    if (can_transmit(&v->bus, id, data, len) == 0) return 0;
    snprintf(error, size, "CAN.Tx_Data is full (%d bytes of operations not read by the importer)",
             CAN_TX_CAPACITY);
    return -1;
}

static int emcy(FmuValues *v, int node, uint16_t code, char *error, size_t size) {
    uint8_t data[8] = {0};
    can_put16(data, code);
    data[2] = ERROR_REGISTER_COMMUNICATION;
    return send(v, 0x080u + (uint32_t)node + 1u, data, 8, error, size);
}

static int32_t saturate32(double x) {
    return x >= 2147483647.0 ? 2147483647 : x <= -2147483648.0 ? INT32_MIN : (int32_t)x;
}

static void leave_operational(FmuValues *v, int node) {
    if (v->bus.nmt[node] == NMT_OPERATIONAL && node < CAN_N_DRIVES &&
        v->bus.drive[node].state == ST_OPERATION_ENABLED)
        fault(&v->bus.drive[node]); /* 0x6007 = 1 */
}

static int nmt_command(FmuValues *v, uint8_t command, int node, char *error, size_t size) {
    FmuBusState *b = &v->bus;
    switch (command) {
    case 0x01: b->nmt[node] = NMT_OPERATIONAL; return 0;
    case 0x02: leave_operational(v, node); b->nmt[node] = NMT_STOPPED; return 0;
    case 0x80: leave_operational(v, node); b->nmt[node] = NMT_PRE_OPERATIONAL; return 0;
    case 0x81:
    case 0x82: {
        leave_operational(v, node);
        if (command == 0x81 && node < CAN_N_DRIVES) reset_application(&b->drive[node]);
        b->nmt[node] = NMT_PRE_OPERATIONAL;
        uint8_t boot = 0;
        return send(v, 0x700u + (uint32_t)node + 1u, &boot, 1, error, size);
    }
    default: return 0; /* not an NMT command: ignored, as a device does */
    }
}

static int sync(FmuValues *v, char *error, size_t size) {
    FmuBusState *b = &v->bus;
    CanDriveData data;
    plant_can_drive_data(v, &data);
    for (int i = 0; i < CAN_N_DRIVES; i++) {                                     /* 1 */
        CanDrive *d = &b->drive[i];
        if (b->nmt[i] == NMT_OPERATIONAL && d->rx_pending) {
            d->rx_pending = false;
            apply_controlword(d, d->rx_controlword);
            d->target_torque = d->rx_target_torque;
        }
    }
    for (int i = 0; i < CAN_N_DRIVES; i++) latch_torque(&b->drive[i], &data);    /* 2 */
    double position[4], velocity[4], alpha[2];                                  /* 3 */
    if (plant_can_sensors(v, position, velocity, alpha) != 0) {
        snprintf(error, size, "the plant's outputs cannot be calculated at the SYNC");
        return -1;
    }
    b->last_sync = v->time, b->sync_seen = true;
    for (int i = 0; i < CAN_N_DRIVES; i++) {                                     /* 4 */
        if (b->nmt[i] != NMT_OPERATIONAL) continue;
        const CanDrive *d = &b->drive[i];
        double counts = floor(position[i] / TWO_PI * data.encoder_increments);
        uint32_t raw = (uint32_t)(int64_t)fmod(counts, 4294967296.0); /* wraps like the drive's counter */
        uint8_t tpdo1[6], tpdo2[6];
        can_put16(tpdo1, d->statusword);
        can_put32(tpdo1 + 2, raw);
        can_put32(tpdo2, (uint32_t)saturate32(rint(velocity[i] / TWO_PI * data.encoder_increments)));
        can_put16(tpdo2 + 4, (uint16_t)(int16_t)d->applied_torque);
        if (send(v, 0x180u + (uint32_t)i + 1u, tpdo1, 6, error, size) ||
            send(v, 0x280u + (uint32_t)i + 1u, tpdo2, 6, error, size))
            return -1;
    }
    for (int j = 0; j < CAN_N_ENCODERS; j++) {
        int node = CAN_N_DRIVES + j;
        if (b->nmt[node] != NMT_OPERATIONAL) continue;
        double full = ldexp(1.0, data.steering_sensor_bits);
        double counts = fmod(rint(alpha[j] / TWO_PI * full), full);
        if (counts < 0) counts += full;
        uint8_t tpdo[4];
        can_put32(tpdo, (uint32_t)counts);
        if (send(v, 0x180u + (uint32_t)node + 1u, tpdo, 4, error, size)) return -1;
    }
    return 0;
}

int can_nodes_boot(FmuValues *v, char *error, size_t size) {
    for (int n = 0; n < CAN_N_NODES; n++)
        if (nmt_command(v, 0x81, n, error, size)) return -1; /* power on: as a reset node */
    return 0;
}

int can_nodes_receive(FmuValues *v, uint32_t id, const uint8_t *data, uint8_t len, char *error, size_t size) {
    FmuBusState *b = &v->bus;
    if (id == 0x000) {                                                 /* NMT: command, node (0 = all) */
        if (len != 2) return 0;
        for (int n = 0; n < CAN_N_NODES; n++)
            if (data[1] == 0 || data[1] == n + 1)
                if (nmt_command(v, data[0], n, error, size)) return -1;
        return 0;
    }
    if (id == 0x080) return len <= 1 ? sync(v, error, size) : 0;
    if (id >= 0x201 && id <= 0x200u + CAN_N_DRIVES) {                  /* drive RPDO1 */
        int i = (int)(id - 0x201);
        if (b->nmt[i] != NMT_OPERATIONAL || len < 4) return 0;         /* PDOs in OPERATIONAL only */
        CanDrive *d = &b->drive[i];
        d->rx_controlword = (uint16_t)(data[0] | data[1] << 8);
        d->rx_target_torque = (int16_t)(uint16_t)(data[2] | data[3] << 8);
        d->rx_pending = true;
    }
    return 0; /* anything else (SDO, other nodes' frames) is not for the PDO path */
}

int can_nodes_supervise(FmuValues *v, char *error, size_t size) {
    FmuBusState *b = &v->bus;
    CanDriveData data;
    plant_can_drive_data(v, &data);
    if (!(data.sync_timeout > 0.0) || !b->sync_seen || v->time - b->last_sync <= data.sync_timeout) return 0;
    b->sync_seen = false; /* reported once per loss */
    for (int n = 0; n < CAN_N_NODES; n++) {
        if (b->nmt[n] != NMT_OPERATIONAL) continue;
        if (n < CAN_N_DRIVES && b->drive[n].state == ST_OPERATION_ENABLED) fault(&b->drive[n]);
        if (emcy(v, n, EMCY_COMMUNICATION, error, size)) return -1;
    }
    return 0;
}

void can_nodes_applied_torque(const FmuValues *v, double u[4]) {
    CanDriveData data;
    plant_can_drive_data(v, &data);
    for (int i = 0; i < CAN_N_DRIVES; i++) u[i] = v->bus.drive[i].applied_torque * (data.rated_torque / 1000.0);
}
