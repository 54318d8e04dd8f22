/* lsbus_can.c -- the plant-can FMU's bus terminal: FMI-LS-BUS network abstraction for CAN (FMI-LS-BUS
 * 1.0, "Network Abstraction": Tx/Rx Data variables, Clocks, the Layered Standard Bus Protocol; "CAN":
 * operation codes and formats). One terminal `CAN`: Rx_Data (Binary input) clocked by Rx_Clock (input,
 * triggered), Tx_Data (Binary output) clocked by Tx_Clock (output, triggered).
 *
 * Operations are little-endian {op code u32, total length u32, arguments}. Received: CAN Transmit (0x10;
 * id u32, ide u8, rtr u8, data length u16, data) is handed to the nodes when it is a classic data frame
 * with an 11-bit id (the CANopen frames); CAN FD / XL frames, remote and extended frames reach no
 * CANopen node of this vehicle and are dropped. Confirm, Arbitration Lost, Bus Error, Configuration,
 * Status, Wakeup and Format Error carry nothing a node without bus notifications acts on. An operation
 * that is truncated, has an unknown op code or a length that does not match its arguments is answered by
 * a Format Error operation (0x01, with the operation's bytes) in Tx_Data and a warning; the operations
 * after a truncated one cannot be delimited and are part of it.
 *
 * Event Mode (FMI 3.0 section 4.2.3): the importer activates Rx_Clock and sets Rx_Data, then calls
 * UpdateDiscreteStates, which processes the operations in order (a SYNC among them runs the nodes' SYNC
 * cycle at the current time; operations still unprocessed at EnterStepMode are processed there). Tx_Clock is active while transmitted frames wait: in the same Event Mode
 * (GetClock) and, if the importer leaves Event Mode without reading Tx_Data, at the end of the next DoStep
 * (eventHandlingNeeded, the triggered Tx_Clock of the standard). Reading Tx_Data hands the operations
 * over. */
#include <stdio.h>
#include <string.h>

#include "plant_can.h"

#define OP_FORMAT_ERROR 0x0001u
#define OP_CAN_TRANSMIT 0x0010u
#define OP_CANFD_TRANSMIT 0x0011u
#define OP_CANXL_TRANSMIT 0x0012u
#define OP_CONFIRM 0x0020u
#define OP_ARBITRATION_LOST 0x0030u
#define OP_BUS_ERROR 0x0031u
#define OP_CONFIGURATION 0x0040u
#define OP_STATUS 0x0041u
#define OP_WAKEUP 0x0042u

#define HEADER 8u
#define CAN_TRANSMIT_FIXED 16u /* header + id + ide + rtr + data length */

static int append(FmuBusState *b, const uint8_t *op, uint32_t length) {
    if (b->tx_size + length > CAN_TX_CAPACITY) return -1;
    memcpy(b->tx + b->tx_size, op, length);
    b->tx_size += length;
    return 0;
}

int can_transmit(FmuBusState *b, uint32_t id, const uint8_t *data, uint8_t len) {
    uint8_t op[CAN_TRANSMIT_FIXED + 8];
    can_put32(op, OP_CAN_TRANSMIT);
    can_put32(op + 4, CAN_TRANSMIT_FIXED + len);
    can_put32(op + 8, id);
    op[12] = 0; /* ide: standard 11-bit identifier */
    op[13] = 0; /* rtr: data frame */
    can_put16(op + 14, len);
    memcpy(op + 16, data, len);
    return append(b, op, CAN_TRANSMIT_FIXED + len);
}

static FmuStatus format_error(FmuInstance *instance, const uint8_t *op, uint32_t n, const char *why) {
    FmuBusState *b = &instance->values.bus;
    uint8_t header[10];
    if (n > CAN_TX_CAPACITY - 10u) n = CAN_TX_CAPACITY - 10u; /* the offending bytes, as many as fit */
    can_put32(header, OP_FORMAT_ERROR);
    can_put32(header + 4, 10u + n);
    can_put16(header + 8, n);
    if (b->tx_size + 10u + n > CAN_TX_CAPACITY)
        return fmu_error(instance, "CAN.Rx_Data: %s; CAN.Tx_Data is full, the Format Error cannot be sent", why);
    append(b, header, 10);
    append(b, op, n);
    fmu_log(instance, FMU_WARNING, FMU_LOG_WARNING, "CAN.Rx_Data: %s (answered by a Format Error operation)", why);
    return FMU_WARNING;
}

static FmuStatus process(FmuInstance *instance) {
    FmuBusState *b = &instance->values.bus;
    FmuStatus status = FMU_OK;
    uint32_t size = b->rx_size, at = 0;
    char text[256];
    while (at < size) {
        const uint8_t *op = b->rx + at;
        uint32_t left = size - at;
        if (left < HEADER) {
            snprintf(text, sizeof text, "%u bytes at offset %u are not an operation header", left, at);
            return format_error(instance, op, left, text);
        }
        uint32_t code = can_get32(op), length = can_get32(op + 4);
        if (length < HEADER || length > left) {
            snprintf(text, sizeof text, "operation 0x%04X at offset %u declares %u bytes, %u are there", code, at,
                     length, left);
            return format_error(instance, op, left, text);
        }
        at += length;
        switch (code) {
        case OP_CAN_TRANSMIT: {
            uint32_t data_length = length >= CAN_TRANSMIT_FIXED ? (uint32_t)(op[14] | op[15] << 8) : 0;
            if (length < CAN_TRANSMIT_FIXED || length != CAN_TRANSMIT_FIXED + data_length || data_length > 64) {
                snprintf(text, sizeof text, "CAN Transmit at offset %u: length %u does not match its data length",
                         at - length, length);
                status = format_error(instance, op, length, text);
                if (status == FMU_ERROR) return status;
                continue;
            }
            uint32_t id = can_get32(op + 8);
            if (op[12] || op[13] || data_length > 8 || id > 0x7FFu) continue; /* no CANopen frame */
            char error[256] = "";
            if (can_nodes_receive(&instance->values, id, op + 16, (uint8_t)data_length, error, sizeof error))
                return fmu_error(instance, "CAN frame 0x%03X at t = %.17g: %s", (unsigned)id, instance->values.time,
                                 error);
            instance->values.dirty = true;
            break;
        }
        case OP_CANFD_TRANSMIT: case OP_CANXL_TRANSMIT: case OP_CONFIRM: case OP_ARBITRATION_LOST:
        case OP_BUS_ERROR: case OP_CONFIGURATION: case OP_STATUS: case OP_WAKEUP: case OP_FORMAT_ERROR:
            break;
        default:
            snprintf(text, sizeof text, "unknown operation code 0x%04X at offset %u", code, at - length);
            status = format_error(instance, op, length, text);
            if (status == FMU_ERROR) return status;
        }
    }
    return status;
}

/* ---- the fmu_bus_* hooks of fmu_instance.h ------------------------------------------------------------ */
FmuStatus fmu_bus_start(FmuInstance *instance) {
    char error[256] = "";
    if (can_nodes_boot(&instance->values, error, sizeof error)) return fmu_error(instance, "boot: %s", error);
    return FMU_OK;
}

static FmuStatus require_event_mode(FmuInstance *instance, const char *function) {
    return fmu_require_mode(instance, FMU_MODE_EVENT, function);
}

FmuStatus fmu_bus_set_clock(FmuInstance *instance, const uint32_t vr[], size_t n, const bool value[]) {
    if (require_event_mode(instance, "SetClock") != FMU_OK) return FMU_ERROR;
    if (n && (!vr || !value)) return fmu_error(instance, "SetClock: NULL array argument");
    for (size_t i = 0; i < n; i++) {
        if (vr[i] != PL_RX_CLOCK)
            return fmu_error(instance, "SetClock: value reference %u is not the input clock CAN.Rx_Clock (%u)",
                             (unsigned)vr[i], (unsigned)PL_RX_CLOCK);
        if (value[i]) instance->values.bus.rx_clock = true;
    }
    return FMU_OK;
}

/* Clocks tick at events only: outside Event Mode (an importer recording every output) they read inactive and
 * the clocked Tx_Data is empty, handing nothing over. */
FmuStatus fmu_bus_get_clock(FmuInstance *instance, const uint32_t vr[], size_t n, bool value[]) {
    if (fmu_require_mode(instance, FMU_MODE_INITIALIZATION | FMU_MODE_RUNNING, "GetClock") != FMU_OK)
        return FMU_ERROR;
    if (n && (!vr || !value)) return fmu_error(instance, "GetClock: NULL array argument");
    for (size_t i = 0; i < n; i++) {
        if (vr[i] != PL_TX_CLOCK)
            return fmu_error(instance, "GetClock: value reference %u is not the output clock CAN.Tx_Clock (%u)",
                             (unsigned)vr[i], (unsigned)PL_TX_CLOCK);
        value[i] = instance->mode == FMU_MODE_EVENT && instance->values.bus.tx_size > 0;
    }
    return FMU_OK;
}

FmuStatus fmu_bus_set_binary(FmuInstance *instance, const uint32_t vr[], size_t n, const size_t size[],
                             const uint8_t *const value[]) {
    if (require_event_mode(instance, "SetBinary") != FMU_OK) return FMU_ERROR;
    if (n && (!vr || !value || !size)) return fmu_error(instance, "SetBinary: NULL array argument");
    FmuBusState *b = &instance->values.bus;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] != PL_RX_DATA)
            return fmu_error(instance, "SetBinary: value reference %u is not the input CAN.Rx_Data (%u)",
                             (unsigned)vr[i], (unsigned)PL_RX_DATA);
        if (!b->rx_clock)
            return fmu_error(instance, "SetBinary: CAN.Rx_Data is clocked by CAN.Rx_Clock, which is not active "
                                       "(call SetClock first)");
        if (size[i] > CAN_RX_CAPACITY)
            return fmu_error(instance, "SetBinary: CAN.Rx_Data of %zu bytes exceeds its maxSize %d", size[i],
                             CAN_RX_CAPACITY);
        if (size[i] && !value[i]) return fmu_error(instance, "SetBinary: NULL value of %zu bytes", size[i]);
        if (size[i]) memcpy(b->rx, value[i], size[i]);
        b->rx_size = (uint32_t)size[i];
    }
    return FMU_OK;
}

FmuStatus fmu_bus_get_binary(FmuInstance *instance, const uint32_t vr[], size_t n, size_t size[],
                             const uint8_t *value[]) {
    if (!instance) return FMU_ERROR;
    if (n && (!vr || !value || !size)) return fmu_error(instance, "GetBinary: NULL array argument");
    FmuBusState *b = &instance->values.bus;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] == PL_TX_DATA && instance->mode != FMU_MODE_EVENT) {
            size[i] = 0;
            value[i] = b->tx;
        } else if (vr[i] == PL_TX_DATA) {
            size[i] = b->tx_size;
            value[i] = b->tx;
            b->tx_size = 0; /* handed over; the bytes stay valid until the next call that transmits */
        } else if (vr[i] == PL_RX_DATA) {
            size[i] = b->rx_size;
            value[i] = b->rx;
        } else {
            return fmu_error(instance, "GetBinary: value reference %u is not a Binary variable", (unsigned)vr[i]);
        }
    }
    return FMU_OK;
}

FmuStatus fmu_bus_update(FmuInstance *instance) {
    if (require_event_mode(instance, "UpdateDiscreteStates") != FMU_OK) return FMU_ERROR;
    FmuBusState *b = &instance->values.bus;
    if (!b->rx_clock) return FMU_OK;
    FmuStatus s = process(instance);
    b->rx_clock = false;
    b->rx_size = 0;
    return s;
}

bool fmu_bus_pending(const FmuInstance *instance) { return instance->values.bus.tx_size > 0; }
