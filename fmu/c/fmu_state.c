/* fmu_state.c -- the FMU state of the generic core (fmu_instance.h): get, set, free, serialize. The state
 * is the instance's mode and all its values (FmuValues); the serialized form carries a header with the
 * format version and the instantiation token, so bytes of another model or export are refused. */
#include "fmu_instance.h"

#include <string.h>

#define STATE_MAGIC 0x51464d55u /* "QFMU" */
#define SERIAL_MAGIC "QOMNIFMU"
#define SERIAL_VERSION 2u
#define TOKEN_SIZE 64

typedef struct {
    uint32_t magic;
    FmuMode mode;
    FmuValues values;
} FmuState;

typedef struct {
    char magic[8];
    uint32_t version;
    uint32_t size;
    uint32_t mode;
    char token[TOKEN_SIZE];
} FmuSerialHeader;

/* The state `state` to write into (as function `who`): itself when it is one of this FMU's, a new one when
 * it is NULL; anything else, or no memory, is an error. */
static FmuStatus writable_state(FmuInstance *instance, void *state, const char *who, FmuState **out) {
    FmuState *st = state;
    if (st && st->magic != STATE_MAGIC) return fmu_error(instance, "%s: not a state of this FMU", who);
    if (!st) {
        st = fmu_allocate(instance, sizeof *st);
        if (!st) return fmu_error(instance, "%s: out of memory", who);
    }
    st->magic = STATE_MAGIC;
    *out = st;
    return FMU_OK;
}

FmuStatus fmu_get_state(FmuInstance *instance, void **state) {
    FmuStatus s = fmu_require_mode(instance, FMU_MODE_ANY, "GetFMUState");
    if (s != FMU_OK) return s;
    if (!state) return fmu_error(instance, "GetFMUState: state pointer is NULL");
    FmuState *st;
    s = writable_state(instance, *state, "GetFMUState", &st);
    if (s != FMU_OK) return s;
    st->mode = instance->mode;
    st->values = instance->values;
    *state = st;
    return FMU_OK;
}

FmuStatus fmu_set_state(FmuInstance *instance, const void *state) {
    FmuStatus s = fmu_require_mode(instance, FMU_MODE_ANY, "SetFMUState");
    if (s != FMU_OK) return s;
    const FmuState *st = state;
    if (!st || st->magic != STATE_MAGIC) return fmu_error(instance, "SetFMUState: not a state of this FMU");
    instance->values = st->values;
    instance->mode = st->mode;
    return FMU_OK;
}

FmuStatus fmu_free_state(FmuInstance *instance, void **state) {
    if (!instance) return FMU_ERROR;
    if (!state || !*state) return FMU_OK;
    FmuState *st = *state;
    if (st->magic != STATE_MAGIC) return fmu_error(instance, "FreeFMUState: not a state of this FMU");
    st->magic = 0;
    fmu_release(instance, st);
    *state = NULL;
    return FMU_OK;
}

size_t fmu_serialized_state_size(void) { return sizeof(FmuSerialHeader) + sizeof(FmuValues); }

FmuStatus fmu_serialize_state(FmuInstance *instance, const void *state, uint8_t buffer[], size_t size) {
    if (!instance) return FMU_ERROR;
    const FmuState *st = state;
    if (!st || st->magic != STATE_MAGIC) return fmu_error(instance, "SerializeFMUState: not a state of this FMU");
    if (!buffer || size < fmu_serialized_state_size())
        return fmu_error(instance, "SerializeFMUState: buffer of %zu bytes, need %zu", size,
                         fmu_serialized_state_size());
    FmuSerialHeader header;
    memset(&header, 0, sizeof header);
    memcpy(header.magic, SERIAL_MAGIC, sizeof header.magic);
    header.version = SERIAL_VERSION;
    header.size = (uint32_t)sizeof(FmuValues);
    header.mode = (uint32_t)st->mode;
    strncpy(header.token, INSTANTIATION_TOKEN, TOKEN_SIZE - 1);
    memcpy(buffer, &header, sizeof header);
    memcpy(buffer + sizeof header, &st->values, sizeof st->values);
    return FMU_OK;
}

FmuStatus fmu_deserialize_state(FmuInstance *instance, const uint8_t buffer[], size_t size, void **state) {
    if (!instance) return FMU_ERROR;
    if (!buffer || !state) return fmu_error(instance, "DeserializeFMUState: NULL argument");
    if (size != fmu_serialized_state_size())
        return fmu_error(instance, "DeserializeFMUState: %zu bytes, expected %zu", size,
                         fmu_serialized_state_size());
    FmuSerialHeader header;
    memcpy(&header, buffer, sizeof header);
    char token[TOKEN_SIZE] = "";
    strncpy(token, INSTANTIATION_TOKEN, TOKEN_SIZE - 1);
    if (memcmp(header.magic, SERIAL_MAGIC, sizeof header.magic) != 0 || header.version != SERIAL_VERSION ||
        header.size != sizeof(FmuValues) || memcmp(header.token, token, TOKEN_SIZE) != 0)
        return fmu_error(instance, "DeserializeFMUState: the bytes are not a state of this FMU "
                                   "(other model, export or format version)");
    if (header.mode != FMU_MODE_INSTANTIATED && header.mode != FMU_MODE_INITIALIZATION &&
        header.mode != FMU_MODE_STEP && header.mode != FMU_MODE_TERMINATED && header.mode != FMU_MODE_EVENT)
        return fmu_error(instance, "DeserializeFMUState: corrupt state (mode %u)", (unsigned)header.mode);
    FmuState *st;
    FmuStatus s = writable_state(instance, *state, "DeserializeFMUState", &st);
    if (s != FMU_OK) return s;
    st->mode = (FmuMode)header.mode;
    memcpy(&st->values, buffer + sizeof header, sizeof st->values);
    *state = st;
    return FMU_OK;
}
