/* bus_state.h -- the CAN side of the plant-can FMU: the vehicle's CANopen nodes behind one FMI-LS-BUS CAN
 * bus terminal (network abstraction). Plain data, no pointers: it is part of FmuValues and so of the FMU
 * state (get/set/serialize).
 *
 * Nodes (docs/conventions.md, "CANopen mapping (hil)"): CiA 402 drives 1..4 (wheels fl, rl, fr, rr),
 * CiA 406 steering encoders 5, 6 (alpha_l, alpha_r). PDO path only, default mapping of the EDS files in
 * hil/eds: drive RPDO1 0x200+id = controlword 0x6040 (UNSIGNED16) + target torque 0x6071 (INTEGER16);
 * TPDO1 0x180+id = statusword 0x6041 + position actual 0x6064 (INTEGER32), TPDO2 0x280+id = velocity
 * actual 0x606C (INTEGER32) + torque actual 0x6077 (INTEGER16); encoder TPDO1 0x180+id = position value
 * 0x6004 (UNSIGNED32); all synchronous (transmission type 1). SYNC 0x080, NMT 0x000, boot-up 0x700+id,
 * EMCY 0x080+id.
 */
#ifndef QOMNI_BUS_STATE_H
#define QOMNI_BUS_STATE_H

#include <stdbool.h>
#include <stdint.h>

#define CAN_N_DRIVES 4
#define CAN_N_ENCODERS 2
#define CAN_N_NODES (CAN_N_DRIVES + CAN_N_ENCODERS)
/* Most bytes of bus operations one Rx_Data / Tx_Data value holds: their declared maxSize (config.h). */
#define CAN_RX_CAPACITY PL_RX_DATA_MAX_SIZE
#define CAN_TX_CAPACITY PL_TX_DATA_MAX_SIZE

typedef struct {
    uint16_t state;             /* CiA 402 power state coding (statusword bits 0..3, 5, 6) */
    uint16_t statusword;        /* 0x6041 as last computed */
    uint16_t controlword;       /* 0x6040 in effect */
    int16_t target_torque;      /* 0x6071 in effect, per mille of 0x6076 */
    uint16_t rx_controlword;    /* RPDO received since the last SYNC (applied at the next SYNC) */
    int16_t rx_target_torque;
    bool rx_pending;
    bool limited;               /* target clipped by 0x6072 in this cycle (statusword bit 11) */
    int32_t applied_torque;     /* per mille of 0x6076, applied from the last SYNC on */
} CanDrive;

typedef struct {
    uint8_t nmt[CAN_N_NODES];   /* NMT state: 0x7F pre-operational, 0x05 operational, 0x04 stopped */
    CanDrive drive[CAN_N_DRIVES];
    double last_sync;           /* s, time of the last SYNC (SYNC-loss supervision) */
    bool sync_seen;
    bool rx_clock;              /* Rx_Clock activated in the current Event Mode */
    uint32_t rx_size;
    uint8_t rx[CAN_RX_CAPACITY];
    uint32_t tx_size;           /* Tx operations waiting for the importer (Tx_Clock active while > 0) */
    uint8_t tx[CAN_TX_CAPACITY];
} FmuBusState;

#endif /* QOMNI_BUS_STATE_H */
