/* fmi2Functions.c -- generic FMI 2.0 Co-Simulation API layer of the qomni FMUs.
 *
 * Exports every function of fmi2Functions.h (FMI 2.0.x, chapter 2 common functions, chapter 4
 * Co-Simulation). Model Exchange functions (chapter 3), directional derivatives and input/output
 * derivatives are not supported: they log an error and return fmi2Error. The model behind this layer
 * is described by config.h and model.c (see fmu_instance.h).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "fmu_instance.h"

#define INSTANCE ((FmuInstance *)c)

static fmi2Status status2(FmuStatus s) { return (fmi2Status)s; }

static void logger2(FmuCallback callback, void *environment, const char *instance_name, FmuStatus status,
                    const char *category, const char *message) {
    /* fmi2CallbackLogger takes a printf format: escape '%' */
    char escaped[2 * FMU_MESSAGE_SIZE];
    size_t j = 0;
    for (size_t i = 0; message[i] && j + 2 < sizeof escaped; i++) {
        if (message[i] == '%') escaped[j++] = '%';
        escaped[j++] = message[i];
    }
    escaped[j] = '\0';
    ((fmi2CallbackLogger)callback)(environment, instance_name, (fmi2Status)status, category, escaped);
}

/* ---- 2.1.4 inquire platform and version ---------------------------------------------------------- */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    return status2(fmu_set_debug_logging(INSTANCE, loggingOn != fmi2False, nCategories, categories));
}

/* ---- 2.1.5 creation, destruction ------------------------------------------------------------------ */
fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    (void)fmuResourceLocation;
    (void)visible;
    FmuCallback callback = (functions && functions->logger) ? (FmuCallback)functions->logger : NULL;
    void *environment = functions ? functions->componentEnvironment : NULL;
    if (fmuType != fmi2CoSimulation) {
        if (callback)
            logger2(callback, environment, instanceName ? instanceName : "", FMU_ERROR, FMU_LOG_ERROR,
                    "fmi2Instantiate: this FMU supports Co-Simulation only (fmuType fmi2CoSimulation)");
        return NULL;
    }
    void *(*allocate)(size_t, size_t) = NULL;
    void (*release)(void *) = NULL;
    if (functions && functions->allocateMemory && functions->freeMemory) {
        allocate = functions->allocateMemory;
        release = functions->freeMemory;
    }
    return fmu_instantiate(instanceName, fmuGUID, logger2, callback, environment, loggingOn != fmi2False,
                           allocate, release);
}

void fmi2FreeInstance(fmi2Component c) { fmu_free_instance(INSTANCE); }

/* ---- 2.1.6 initialization, termination, reset ------------------------------------------------------ */
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    FmuStatus s = fmu_require_mode(INSTANCE, FMU_MODE_INSTANTIATED, "fmi2SetupExperiment");
    if (s != FMU_OK) return status2(s);
    INSTANCE->values.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    if (!c) return fmi2Error;
    return status2(fmu_enter_initialization(INSTANCE, INSTANCE->values.time));
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) { return status2(fmu_exit_initialization(INSTANCE)); }

fmi2Status fmi2Terminate(fmi2Component c) { return status2(fmu_terminate(INSTANCE)); }

fmi2Status fmi2Reset(fmi2Component c) { return status2(fmu_reset(INSTANCE)); }

/* ---- 2.1.7 getting and setting variable values ---------------------------------------------------- */
fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    return status2(fmu_get_float64(INSTANCE, vr, nvr, value));
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    return status2(fmu_get_int32(INSTANCE, vr, nvr, (int32_t *)value));
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    if (!c) return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        bool b = false;
        FmuStatus s = fmu_get_boolean(INSTANCE, &vr[i], 1, &b);
        if (s != FMU_OK) return status2(s);
        value[i] = b ? fmi2True : fmi2False;
    }
    return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    (void)vr;
    (void)value;
    return status2(fmu_no_variables_of_type(INSTANCE, "String", nvr));
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    return status2(fmu_set_float64(INSTANCE, vr, nvr, value));
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    return status2(fmu_set_int32(INSTANCE, vr, nvr, (const int32_t *)value));
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    if (!c) return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        bool b = value[i] != fmi2False;
        FmuStatus s = fmu_set_boolean(INSTANCE, &vr[i], 1, &b);
        if (s != FMU_OK) return status2(s);
    }
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    (void)vr;
    (void)value;
    return status2(fmu_no_variables_of_type(INSTANCE, "String", nvr));
}

/* ---- 2.1.8 getting and setting the complete FMU state ---------------------------------------------- */
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    return status2(fmu_get_state(INSTANCE, FMUstate));
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    return status2(fmu_set_state(INSTANCE, FMUstate));
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    return status2(fmu_free_state(INSTANCE, FMUstate));
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    (void)FMUstate;
    if (!c) return fmi2Error;
    if (!size) return status2(fmu_unsupported(INSTANCE, "fmi2SerializedFMUstateSize with size == NULL"));
    *size = fmu_serialized_state_size();
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                 size_t size) {
    return status2(fmu_serialize_state(INSTANCE, FMUstate, (uint8_t *)serializedState, size));
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    return status2(fmu_deserialize_state(INSTANCE, (const uint8_t *)serializedState, size, FMUstate));
}

/* ---- 2.1.9 partial derivatives (outputs by inputs, exact: fmu_model_jacobian) ---------------------- */
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    return status2(fmu_derivatives(INSTANCE, vUnknown_ref, nUnknown, vKnown_ref, nKnown, dvKnown, nKnown, dvUnknown,
                                   nUnknown, false, "fmi2GetDirectionalDerivative"));
}

/* ---- chapter 3 Model Exchange (not supported) ------------------------------------------------------ */
fmi2Status fmi2EnterEventMode(fmi2Component c) { return status2(fmu_unsupported(INSTANCE, "fmi2EnterEventMode")); }

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *eventInfo) {
    (void)eventInfo;
    return status2(fmu_unsupported(INSTANCE, "fmi2NewDiscreteStates"));
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    return status2(fmu_unsupported(INSTANCE, "fmi2EnterContinuousTimeMode"));
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint, (void)enterEventMode, (void)terminateSimulation;
    return status2(fmu_unsupported(INSTANCE, "fmi2CompletedIntegratorStep"));
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    (void)time;
    return status2(fmu_unsupported(INSTANCE, "fmi2SetTime"));
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    (void)x, (void)nx;
    return status2(fmu_unsupported(INSTANCE, "fmi2SetContinuousStates"));
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    (void)derivatives, (void)nx;
    return status2(fmu_unsupported(INSTANCE, "fmi2GetDerivatives"));
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    (void)eventIndicators, (void)ni;
    return status2(fmu_unsupported(INSTANCE, "fmi2GetEventIndicators"));
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    (void)x, (void)nx;
    return status2(fmu_unsupported(INSTANCE, "fmi2GetContinuousStates"));
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    (void)x_nominal, (void)nx;
    return status2(fmu_unsupported(INSTANCE, "fmi2GetNominalsOfContinuousStates"));
}

/* ---- chapter 4 Co-Simulation ---------------------------------------------------------------------- */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr, (void)nvr, (void)order, (void)value;
    return status2(fmu_unsupported(INSTANCE, "fmi2SetRealInputDerivatives (canInterpolateInputs=\"false\")"));
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr, (void)nvr, (void)order, (void)value;
    return status2(fmu_unsupported(INSTANCE, "fmi2GetRealOutputDerivatives (maxOutputDerivativeOrder=\"0\")"));
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    (void)noSetFMUStatePriorToCurrentPoint;
    return status2(fmu_do_step(INSTANCE, currentCommunicationPoint, communicationStepSize));
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    return status2(fmu_unsupported(INSTANCE, "fmi2CancelStep (doStep never returns fmi2Pending)"));
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    if (!c) return fmi2Error;
    if (s == fmi2DoStepStatus && value) {
        *value = fmi2OK; /* doStep is synchronous */
        return fmi2OK;
    }
    return status2(fmu_unsupported(INSTANCE, "fmi2GetStatus for this status kind"));
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    if (!c) return fmi2Error;
    if (s == fmi2LastSuccessfulTime && value) {
        *value = INSTANCE->values.time;
        return fmi2OK;
    }
    return status2(fmu_unsupported(INSTANCE, "fmi2GetRealStatus for this status kind"));
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s, (void)value;
    return status2(fmu_unsupported(INSTANCE, "fmi2GetIntegerStatus"));
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    if (!c) return fmi2Error;
    if (s == fmi2Terminated && value) {
        *value = fmi2False; /* the slave never requests termination */
        return fmi2OK;
    }
    return status2(fmu_unsupported(INSTANCE, "fmi2GetBooleanStatus for this status kind"));
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)s, (void)value;
    return status2(fmu_unsupported(INSTANCE, "fmi2GetStringStatus"));
}
