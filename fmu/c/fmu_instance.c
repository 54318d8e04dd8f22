/* fmu_instance.c -- generic core of the qomni Co-Simulation FMUs (see fmu_instance.h). */
#include "fmu_instance.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const FmuVariable fmu_variables[N_VARIABLES] = FMU_VARIABLE_TABLE;
static const double fmu_float64_start[FMU_ARRAY_SIZE(N_FLOAT64)] = FMU_FLOAT64_START;
static const int32_t fmu_int32_start[FMU_ARRAY_SIZE(N_INT32)] = FMU_INT32_START;
static const bool fmu_boolean_start[FMU_ARRAY_SIZE(N_BOOLEAN)] = FMU_BOOLEAN_START;

static const char *const type_names[] = {"Float64", "Int32", "Boolean", "Binary", "Clock"};

/* --- memory and logging --------------------------------------------------------------------------- */
void *fmu_allocate(FmuInstance *instance, size_t size) {
    return instance->allocate ? instance->allocate(1, size) : calloc(1, size);
}

void fmu_release(FmuInstance *instance, void *pointer) {
    if (!pointer) return;
    if (instance->release) instance->release(pointer);
    else free(pointer);
}

static void deliver(FmuLogger logger, FmuCallback callback, void *environment, const char *name,
                    FmuStatus status, const char *category, const char *text) {
    if (logger && callback) logger(callback, environment, name ? name : "", status, category, text);
}

void fmu_log(FmuInstance *instance, FmuStatus status, const char *category, const char *format, ...) {
    if (!instance) return;
    if (status == FMU_OK && !instance->log_calls) return;
    va_list args;
    va_start(args, format);
    vsnprintf(instance->message, sizeof instance->message, format, args);
    va_end(args);
    deliver(instance->logger, instance->callback, instance->environment, instance->name, status, category, instance->message);
}

FmuStatus fmu_error(FmuInstance *instance, const char *format, ...) {
    va_list args;
    va_start(args, format);
    vsnprintf(instance->message, sizeof instance->message, format, args);
    va_end(args);
    deliver(instance->logger, instance->callback, instance->environment, instance->name, FMU_ERROR, FMU_LOG_ERROR,
            instance->message);
    return FMU_ERROR;
}

static const char *mode_name(FmuMode mode) {
    switch (mode) {
    case FMU_MODE_INSTANTIATED: return "Instantiated";
    case FMU_MODE_INITIALIZATION: return "Initialization Mode";
    case FMU_MODE_STEP: return "Step Mode";
    case FMU_MODE_TERMINATED: return "Terminated";
    case FMU_MODE_EVENT: return "Event Mode";
    }
    return "unknown";
}

FmuStatus fmu_require_mode(FmuInstance *instance, unsigned mask, const char *function) {
    if (!instance) return FMU_ERROR;
    if ((unsigned)instance->mode & mask) {
        fmu_log(instance, FMU_OK, FMU_LOG_CALLS, "%s", function);
        return FMU_OK;
    }
    return fmu_error(instance, "%s must not be called in state %s", function, mode_name(instance->mode));
}

FmuStatus fmu_unsupported(FmuInstance *instance, const char *function) {
    if (!instance) return FMU_ERROR;
    return fmu_error(instance, "%s is not supported by this FMU (Co-Simulation only, no event mode, "
                               "no clocks)", function);
}

/* --- life cycle ------------------------------------------------------------------------------------- */
static void set_start_values(FmuValues *v) {
    memset(v, 0, sizeof *v);
    memcpy(v->float64, fmu_float64_start, sizeof v->float64);
    memcpy(v->int32, fmu_int32_start, sizeof v->int32);
    memcpy(v->boolean, fmu_boolean_start, sizeof v->boolean);
    v->time = 0.0;
    v->dirty = true;
}

FmuInstance *fmu_instantiate(const char *name, const char *token, FmuLogger logger, FmuCallback callback,
                             void *environment, bool log_calls, void *(*allocate)(size_t, size_t), void (*release)(void *)) {
    const char *instance_name = name ? name : "";
    if (!token || strcmp(token, INSTANTIATION_TOKEN) != 0) {
        char text[FMU_MESSAGE_SIZE];
        snprintf(text, sizeof text, "instantiation token / GUID '%s' does not match the FMU's '%s' "
                 "(modelDescription.xml and binary of different exports?)",
                 token ? token : "(null)", INSTANTIATION_TOKEN);
        deliver(logger, callback, environment, instance_name, FMU_ERROR, FMU_LOG_ERROR, text);
        return NULL;
    }
    FmuInstance *instance = allocate ? allocate(1, sizeof *instance) : calloc(1, sizeof *instance);
    if (!instance) {
        deliver(logger, callback, environment, instance_name, FMU_ERROR, FMU_LOG_ERROR, "out of memory");
        return NULL;
    }
    memset(instance, 0, sizeof *instance);
    instance->allocate = allocate;
    instance->release = release;
    instance->logger = logger;
    instance->callback = callback;
    instance->environment = environment;
    instance->log_calls = log_calls;
    instance->name = fmu_allocate(instance, strlen(instance_name) + 1);
    if (!instance->name) {
        deliver(logger, callback, environment, instance_name, FMU_ERROR, FMU_LOG_ERROR, "out of memory");
        if (release) release(instance);
        else free(instance);
        return NULL;
    }
    strcpy(instance->name, instance_name);
    instance->mode = FMU_MODE_INSTANTIATED;
    set_start_values(&instance->values);
    for (size_t i = 0; i < N_VARIABLES; i++) {
        if (fmu_variables[i].vr != (uint32_t)i) { /* config.h invariant: value reference == row */
            fmu_error(instance, "corrupt variable table: row %zu has value reference %u", i,
                      (unsigned)fmu_variables[i].vr);
            fmu_free_instance(instance);
            return NULL;
        }
    }
    fmu_log(instance, FMU_OK, FMU_LOG_CALLS, "instantiated %s (token %s)", MODEL_IDENTIFIER_STRING,
            INSTANTIATION_TOKEN);
    return instance;
}

void fmu_free_instance(FmuInstance *instance) {
    if (!instance) return;
    void (*release)(void *) = instance->release;
    if (release) {
        release(instance->name);
        release(instance);
    } else {
        free(instance->name);
        free(instance);
    }
}

FmuStatus fmu_set_debug_logging(FmuInstance *instance, bool on, size_t n, const char *const categories[]) {
    if (!instance) return FMU_ERROR;
    if (n == 0) {
        instance->log_calls = on;
        return FMU_OK;
    }
    if (!categories) return fmu_error(instance, "SetDebugLogging: categories is NULL but nCategories = %zu", n);
    for (size_t i = 0; i < n; i++) {
        const char *c = categories[i];
        if (!c) return fmu_error(instance, "log category %zu is NULL", i);
        if (strcmp(c, FMU_LOG_CALLS) == 0) instance->log_calls = on;
        else if (strcmp(c, FMU_LOG_ERROR) != 0 && strcmp(c, FMU_LOG_WARNING) != 0)
            return fmu_error(instance, "unknown log category '%s' (known: %s, %s, %s)", c, FMU_LOG_ERROR,
                             FMU_LOG_WARNING, FMU_LOG_CALLS);
    }
    return FMU_OK;
}

FmuStatus fmu_enter_initialization(FmuInstance *instance, double start_time) {
    FmuStatus s = fmu_require_mode(instance, FMU_MODE_INSTANTIATED, "EnterInitializationMode");
    if (s != FMU_OK) return s;
    if (!isfinite(start_time)) return fmu_error(instance, "start time %g is not finite", start_time);
    instance->values.time = start_time;
    instance->mode = FMU_MODE_INITIALIZATION;
    return FMU_OK;
}

static FmuStatus initialize_if_needed(FmuInstance *instance) {
    if (instance->values.initialized) return FMU_OK;
    char text[FMU_MESSAGE_SIZE] = "";
    if (fmu_model_initialize(&instance->values, text, sizeof text) != FMU_OK)
        return fmu_error(instance, "cannot set the initial state: %s", text);
    instance->values.initialized = true;
    instance->values.dirty = true;
    return FMU_OK;
}

FmuStatus fmu_exit_initialization(FmuInstance *instance) {
    FmuStatus s = fmu_require_mode(instance, FMU_MODE_INITIALIZATION, "ExitInitializationMode");
    if (s != FMU_OK) return s;
    if (initialize_if_needed(instance) != FMU_OK) return FMU_ERROR;
    instance->mode = instance->event_mode_used ? FMU_MODE_EVENT : FMU_MODE_STEP;
#ifdef FMU_BUS
    if (fmu_bus_start(instance) != FMU_OK) return FMU_ERROR;
#endif
    return FMU_OK;
}

FmuStatus fmu_enter_event_mode(FmuInstance *instance) {
    FmuStatus s = fmu_require_mode(instance, FMU_MODE_STEP, "EnterEventMode");
    if (s != FMU_OK) return s;
    instance->mode = FMU_MODE_EVENT;
    return FMU_OK;
}

FmuStatus fmu_enter_step_mode(FmuInstance *instance) {
    FmuStatus s = fmu_require_mode(instance, FMU_MODE_EVENT, "EnterStepMode");
    if (s != FMU_OK) return s;
#ifdef FMU_BUS
    /* operations received in this Event Mode but not yet processed (no UpdateDiscreteStates) */
    s = fmu_bus_update(instance);
    if (s == FMU_ERROR || s == FMU_FATAL) return s;
#endif
    instance->mode = FMU_MODE_STEP;
    return s;
}

FmuStatus fmu_do_step(FmuInstance *instance, double t, double h) {
    FmuStatus s = fmu_require_mode(instance, FMU_MODE_STEP, "DoStep");
    if (s != FMU_OK) return s;
    if (!(h > 0.0) || !isfinite(h))
        return fmu_error(instance, "communicationStepSize must be > 0 and finite, got %.17g", h);
    double now = instance->values.time;
    if (!isfinite(t) || fabs(t - now) > 1e-9 * fmax(1.0, fabs(now)))
        return fmu_error(instance, "currentCommunicationPoint %.17g differs from the FMU time %.17g", t, now);
    char text[FMU_MESSAGE_SIZE] = "";
    if (fmu_model_do_step(&instance->values, h, text, sizeof text) != FMU_OK)
        return fmu_error(instance, "step from t = %.17g by %.17g s failed: %s", t, h, text);
    instance->values.time = t + h; /* variable communication step size: any h > 0 */
    instance->values.dirty = true;
    return FMU_OK;
}

FmuStatus fmu_terminate(FmuInstance *instance) {
    FmuStatus s = fmu_require_mode(instance, FMU_MODE_INITIALIZATION | FMU_MODE_RUNNING, "Terminate");
    if (s != FMU_OK) return s;
    instance->mode = FMU_MODE_TERMINATED;
    return FMU_OK;
}

FmuStatus fmu_reset(FmuInstance *instance) {
    FmuStatus s = fmu_require_mode(instance, FMU_MODE_ANY, "Reset");
    if (s != FMU_OK) return s;
    set_start_values(&instance->values);
    instance->mode = FMU_MODE_INSTANTIATED;
    return FMU_OK;
}

/* --- variable access ------------------------------------------------------------------------------- */
static const FmuVariable *lookup(FmuInstance *instance, uint32_t vr, FmuType type) {
    if (vr >= N_VARIABLES) {
        fmu_error(instance, "unknown value reference %u", (unsigned)vr);
        return NULL;
    }
    const FmuVariable *v = &fmu_variables[vr];
    if (v->type != type) {
        fmu_error(instance, "variable '%s' (value reference %u) is %s, not %s", v->name, (unsigned)vr,
                  type_names[v->type], type_names[type]);
        return NULL;
    }
    return v;
}

static FmuStatus calculate_if_needed(FmuInstance *instance, const FmuVariable *v) {
    if (v->causality != FMU_OUTPUT) return FMU_OK;
    if (initialize_if_needed(instance) != FMU_OK) return FMU_ERROR;
    if (!instance->values.dirty) return FMU_OK;
    char text[FMU_MESSAGE_SIZE] = "";
    FmuStatus s = fmu_model_calculate(&instance->values, text, sizeof text);
    if (s == FMU_OK) {
        instance->values.dirty = false;
        return FMU_OK;
    }
    return fmu_error(instance, "cannot calculate the outputs at t = %.17g: %s", instance->values.time, text);
}

/* A Float64 input must be finite and within its declared range (FMI 2.0 section 2.2.7, FMI 3.0 section
 * 2.4.7.4: min/max of an input bound the values an importer may set). */
static FmuStatus check_input_value(FmuInstance *instance, const FmuVariable *v, double value) {
    if (v->causality != FMU_INPUT) return FMU_OK;
    if (!isfinite(value)) return fmu_error(instance, "input %s is not finite (got %g)", v->name, value);
    if (value < v->min || value > v->max)
        return fmu_error(instance, "input %s = %.17g is outside its declared range [%g, %g]", v->name, value,
                         v->min, v->max);
    return FMU_OK;
}

static FmuStatus check_settable(FmuInstance *instance, const FmuVariable *v) {
    if (instance->mode == FMU_MODE_TERMINATED)
        return fmu_error(instance, "cannot set '%s' in state Terminated", v->name);
    switch (v->causality) {
    case FMU_INPUT:
        return FMU_OK;
    case FMU_PARAMETER:
        if (v->tunable || !(instance->mode & FMU_MODE_RUNNING)) return FMU_OK;
        return fmu_error(instance, "parameter '%s' is fixed and cannot be set in %s", v->name,
                         mode_name(instance->mode));
    case FMU_OUTPUT:
        return fmu_error(instance, "'%s' is an output and cannot be set", v->name);
    case FMU_INDEPENDENT:
        return fmu_error(instance, "'%s' is the independent variable and cannot be set", v->name);
    }
    return FMU_ERROR;
}

#define CHECK_ARGS(function)                                                                     \
    if (!instance) return FMU_ERROR;                                                             \
    if (n > 0 && (!vr || !value)) return fmu_error(instance, "%s: NULL array argument", function);

FmuStatus fmu_get_float64(FmuInstance *instance, const uint32_t vr[], size_t n, double value[]) {
    CHECK_ARGS("GetFloat64")
    for (size_t i = 0; i < n; i++) {
        const FmuVariable *v = lookup(instance, vr[i], FMU_FLOAT64);
        if (!v) return FMU_ERROR;
        if (v->causality == FMU_INDEPENDENT) {
            value[i] = instance->values.time;
            continue;
        }
        if (calculate_if_needed(instance, v) != FMU_OK) return FMU_ERROR;
        value[i] = instance->values.float64[v->index];
    }
    return FMU_OK;
}

FmuStatus fmu_get_int32(FmuInstance *instance, const uint32_t vr[], size_t n, int32_t value[]) {
    CHECK_ARGS("GetInt32")
    for (size_t i = 0; i < n; i++) {
        const FmuVariable *v = lookup(instance, vr[i], FMU_INT32);
        if (!v || calculate_if_needed(instance, v) != FMU_OK) return FMU_ERROR;
        value[i] = instance->values.int32[v->index];
    }
    return FMU_OK;
}

FmuStatus fmu_get_boolean(FmuInstance *instance, const uint32_t vr[], size_t n, bool value[]) {
    CHECK_ARGS("GetBoolean")
    for (size_t i = 0; i < n; i++) {
        const FmuVariable *v = lookup(instance, vr[i], FMU_BOOLEAN);
        if (!v || calculate_if_needed(instance, v) != FMU_OK) return FMU_ERROR;
        value[i] = instance->values.boolean[v->index];
    }
    return FMU_OK;
}

FmuStatus fmu_set_float64(FmuInstance *instance, const uint32_t vr[], size_t n, const double value[]) {
    CHECK_ARGS("SetFloat64")
    for (size_t i = 0; i < n; i++) {
        const FmuVariable *v = lookup(instance, vr[i], FMU_FLOAT64);
        if (!v || check_settable(instance, v) != FMU_OK || check_input_value(instance, v, value[i]) != FMU_OK)
            return FMU_ERROR;
        instance->values.float64[v->index] = value[i];
        instance->values.dirty = true;
        if (v->causality == FMU_PARAMETER && !(instance->mode & FMU_MODE_RUNNING)) instance->values.initialized = false;
    }
    return FMU_OK;
}

FmuStatus fmu_set_int32(FmuInstance *instance, const uint32_t vr[], size_t n, const int32_t value[]) {
    CHECK_ARGS("SetInt32")
    for (size_t i = 0; i < n; i++) {
        const FmuVariable *v = lookup(instance, vr[i], FMU_INT32);
        if (!v || check_settable(instance, v) != FMU_OK) return FMU_ERROR;
        instance->values.int32[v->index] = value[i];
        instance->values.dirty = true;
        if (v->causality == FMU_PARAMETER && !(instance->mode & FMU_MODE_RUNNING)) instance->values.initialized = false;
    }
    return FMU_OK;
}

FmuStatus fmu_set_boolean(FmuInstance *instance, const uint32_t vr[], size_t n, const bool value[]) {
    CHECK_ARGS("SetBoolean")
    for (size_t i = 0; i < n; i++) {
        const FmuVariable *v = lookup(instance, vr[i], FMU_BOOLEAN);
        if (!v || check_settable(instance, v) != FMU_OK) return FMU_ERROR;
        instance->values.boolean[v->index] = value[i];
        instance->values.dirty = true;
        if (v->causality == FMU_PARAMETER && !(instance->mode & FMU_MODE_RUNNING)) instance->values.initialized = false;
    }
    return FMU_OK;
}

FmuStatus fmu_no_variables_of_type(FmuInstance *instance, const char *type, size_t n) {
    if (!instance) return FMU_ERROR;
    if (n == 0) return FMU_OK;
    return fmu_error(instance, "this FMU has no variables of type %s", type);
}

/* --- partial derivatives ------------------------------------------------------------------------------ */
static const FmuVariable *lookup_causality(FmuInstance *instance, uint32_t vr, FmuCausality causality,
                                           const char *role, const char *function) {
    const FmuVariable *v = lookup(instance, vr, FMU_FLOAT64);
    if (v && v->causality != causality) {
        fmu_error(instance, "%s: %s '%s' (value reference %u) is not a Float64 %s", function, role, v->name,
                  (unsigned)vr, causality == FMU_INPUT ? "input" : "output");
        return NULL;
    }
    return v;
}

FmuStatus fmu_derivatives(FmuInstance *instance, const uint32_t unknowns[], size_t n_unknown,
                          const uint32_t knowns[], size_t n_known, const double seed[], size_t n_seed,
                          double sensitivity[], size_t n_sensitivity, bool adjoint, const char *function) {
    FmuStatus s = fmu_require_mode(instance, FMU_MODE_INITIALIZATION | FMU_MODE_RUNNING, function);
    if (s != FMU_OK) return s;
    size_t want_seed = adjoint ? n_unknown : n_known, want_sensitivity = adjoint ? n_known : n_unknown;
    if (n_seed != want_seed || n_sensitivity != want_sensitivity)
        return fmu_error(instance, "%s: nSeed = %zu and nSensitivity = %zu, expected %zu and %zu", function,
                         n_seed, n_sensitivity, want_seed, want_sensitivity);
    if ((n_unknown && !unknowns) || (n_known && !knowns) || (n_seed && !seed) || (n_sensitivity && !sensitivity))
        return fmu_error(instance, "%s: NULL array argument", function);
    size_t row[FMU_ARRAY_SIZE(N_FLOAT64)], column[FMU_ARRAY_SIZE(N_FLOAT64)];
    if (n_unknown > N_FLOAT64 || n_known > N_FLOAT64)
        return fmu_error(instance, "%s: more unknowns or knowns than Float64 variables", function);
    for (size_t i = 0; i < n_unknown; i++) {
        const FmuVariable *v = lookup_causality(instance, unknowns[i], FMU_OUTPUT, "unknown", function);
        if (!v) return FMU_ERROR;
        row[i] = v->index;
    }
    for (size_t j = 0; j < n_known; j++) {
        const FmuVariable *v = lookup_causality(instance, knowns[j], FMU_INPUT, "known", function);
        if (!v) return FMU_ERROR;
        column[j] = v->index;
    }
    if (initialize_if_needed(instance) != FMU_OK) return FMU_ERROR;
    double J[FMU_ARRAY_SIZE(N_FLOAT64) * FMU_ARRAY_SIZE(N_FLOAT64)];
    char text[FMU_MESSAGE_SIZE] = "";
    if (fmu_model_jacobian(&instance->values, J, text, sizeof text) != FMU_OK)
        return fmu_error(instance, "%s at t = %.17g: %s", function, instance->values.time, text);
    for (size_t i = 0; i < n_sensitivity; i++) sensitivity[i] = 0.0;
    for (size_t i = 0; i < n_unknown; i++) {
        for (size_t j = 0; j < n_known; j++) {
            double d = J[row[i] * N_FLOAT64 + column[j]];
            if (adjoint) sensitivity[j] += seed[i] * d;
            else sensitivity[i] += d * seed[j];
        }
    }
    return FMU_OK;
}
