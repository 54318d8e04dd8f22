/* fmi3Functions.c -- generic FMI 3.0 Co-Simulation API layer of the qomni FMUs.
 *
 * Exports every function of fmi3Functions.h (FMI 3.0, section 2.3 common functions, section 4
 * Co-Simulation). A model with a bus (FMU_BUS in config.h) has Event Mode (section 4.2.3), triggered
 * Clocks and clocked Binary variables, handled by its fmu_bus_* functions; other models have no event
 * mode. Model Exchange (section 3), Scheduled Execution (section 5), configuration mode and the variable
 * types a model does not have log an error and return fmi3Error (the instantiate functions of other
 * interfaces return NULL).
 * The model behind this layer is described by config.h and model.c (see fmu_instance.h).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "fmu_instance.h"

#define INSTANCE ((FmuInstance *)instance)

static fmi3Status status3(FmuStatus s) { return (fmi3Status)s; }

static void logger3(FmuCallback callback, void *environment, const char *instance_name, FmuStatus status,
                    const char *category, const char *message) {
    (void)instance_name;
    ((fmi3LogMessageCallback)callback)(environment, (fmi3Status)status, category, message);
}

static fmi3Status check_n(FmuInstance *inst, size_t nvr, size_t nvalues, const char *function) {
    if (!inst) return fmi3Error;
    if (nvr == nvalues) return fmi3OK;
    fmu_log(inst, FMU_ERROR, FMU_LOG_ERROR, "%s: nValues (%zu) must equal nValueReferences (%zu): all "
            "variables are scalars", function, nvalues, nvr);
    return fmi3Error;
}

/* ---- 2.3.1 inquire version, logging ----------------------------------------------------------------- */
const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    return status3(fmu_set_debug_logging(INSTANCE, loggingOn, nCategories, categories));
}

/* ---- 2.3.1 instantiation ---------------------------------------------------------------------------- */
static void refuse(fmi3String instanceName, fmi3InstanceEnvironment env, fmi3LogMessageCallback logMessage,
                   const char *what) {
    if (logMessage)
        logger3((FmuCallback)logMessage, env, instanceName, FMU_ERROR, FMU_LOG_ERROR, what);
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)instantiationToken, (void)resourcePath, (void)visible, (void)loggingOn;
    refuse(instanceName, instanceEnvironment, logMessage,
           "fmi3InstantiateModelExchange: this FMU supports Co-Simulation only");
    return NULL;
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    (void)resourcePath, (void)visible, (void)earlyReturnAllowed, (void)requiredIntermediateVariables;
    (void)intermediateUpdate;
#ifndef FMU_BUS
    if (eventModeUsed) {
        refuse(instanceName, instanceEnvironment, logMessage,
               "fmi3InstantiateCoSimulation: eventModeUsed = true, but the FMU has no event mode "
               "(hasEventMode=\"false\")");
        return NULL;
    }
#endif
    if (nRequiredIntermediateVariables > 0) {
        refuse(instanceName, instanceEnvironment, logMessage,
               "fmi3InstantiateCoSimulation: intermediate variable access is not provided "
               "(providesIntermediateUpdate=\"false\")");
        return NULL;
    }
    FmuInstance *created = fmu_instantiate(instanceName, instantiationToken, logger3, (FmuCallback)logMessage,
                                           instanceEnvironment, loggingOn, NULL, NULL);
    if (created) created->event_mode_used = eventModeUsed;
    return created;
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible,
                                               fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage,
                                               fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instantiationToken, (void)resourcePath, (void)visible, (void)loggingOn;
    (void)clockUpdate, (void)lockPreemption, (void)unlockPreemption;
    refuse(instanceName, instanceEnvironment, logMessage,
           "fmi3InstantiateScheduledExecution: this FMU supports Co-Simulation only");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) { fmu_free_instance(INSTANCE); }

/* ---- 2.3.2-2.3.4 initialization, termination, reset ----------------------------------------------- */
fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    (void)toleranceDefined, (void)tolerance, (void)stopTimeDefined, (void)stopTime;
    return status3(fmu_enter_initialization(INSTANCE, startTime));
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) { return status3(fmu_exit_initialization(INSTANCE)); }

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
#ifdef FMU_BUS
    return status3(fmu_enter_event_mode(INSTANCE));
#else
    return status3(fmu_unsupported(INSTANCE, "fmi3EnterEventMode (hasEventMode=\"false\")"));
#endif
}

fmi3Status fmi3Terminate(fmi3Instance instance) { return status3(fmu_terminate(INSTANCE)); }

fmi3Status fmi3Reset(fmi3Instance instance) { return status3(fmu_reset(INSTANCE)); }

/* ---- 2.3.5 getting and setting variable values ------------------------------------------------------ */
fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float64 values[], size_t nValues) {
    if (check_n(INSTANCE, nValueReferences, nValues, "fmi3GetFloat64") != fmi3OK) return fmi3Error;
    return status3(fmu_get_float64(INSTANCE, valueReferences, nValueReferences, values));
}

fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, fmi3Int32 values[], size_t nValues) {
    if (check_n(INSTANCE, nValueReferences, nValues, "fmi3GetInt32") != fmi3OK) return fmi3Error;
    return status3(fmu_get_int32(INSTANCE, valueReferences, nValueReferences, values));
}

fmi3Status fmi3GetBoolean(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Boolean values[], size_t nValues) {
    if (check_n(INSTANCE, nValueReferences, nValues, "fmi3GetBoolean") != fmi3OK) return fmi3Error;
    return status3(fmu_get_boolean(INSTANCE, valueReferences, nValueReferences, values));
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float64 values[], size_t nValues) {
    if (check_n(INSTANCE, nValueReferences, nValues, "fmi3SetFloat64") != fmi3OK) return fmi3Error;
    return status3(fmu_set_float64(INSTANCE, valueReferences, nValueReferences, values));
}

fmi3Status fmi3SetInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, const fmi3Int32 values[], size_t nValues) {
    if (check_n(INSTANCE, nValueReferences, nValues, "fmi3SetInt32") != fmi3OK) return fmi3Error;
    return status3(fmu_set_int32(INSTANCE, valueReferences, nValueReferences, values));
}

fmi3Status fmi3SetBoolean(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Boolean values[], size_t nValues) {
    if (check_n(INSTANCE, nValueReferences, nValues, "fmi3SetBoolean") != fmi3OK) return fmi3Error;
    return status3(fmu_set_boolean(INSTANCE, valueReferences, nValueReferences, values));
}

/* Types this model has no variables of: an error for any value reference. */
#define NO_VARIABLES_GET(Type, CType)                                                                    \
    fmi3Status fmi3Get##Type(fmi3Instance instance, const fmi3ValueReference valueReferences[],          \
                             size_t nValueReferences, CType values[], size_t nValues) {                 \
        (void)valueReferences, (void)values, (void)nValues;                                             \
        return status3(fmu_no_variables_of_type(INSTANCE, #Type, nValueReferences));                    \
    }
#define NO_VARIABLES_SET(Type, CType)                                                                    \
    fmi3Status fmi3Set##Type(fmi3Instance instance, const fmi3ValueReference valueReferences[],          \
                             size_t nValueReferences, const CType values[], size_t nValues) {           \
        (void)valueReferences, (void)values, (void)nValues;                                             \
        return status3(fmu_no_variables_of_type(INSTANCE, #Type, nValueReferences));                    \
    }

NO_VARIABLES_GET(Float32, fmi3Float32)
NO_VARIABLES_GET(Int8, fmi3Int8)
NO_VARIABLES_GET(UInt8, fmi3UInt8)
NO_VARIABLES_GET(Int16, fmi3Int16)
NO_VARIABLES_GET(UInt16, fmi3UInt16)
NO_VARIABLES_GET(UInt32, fmi3UInt32)
NO_VARIABLES_GET(Int64, fmi3Int64)
NO_VARIABLES_GET(UInt64, fmi3UInt64)
NO_VARIABLES_GET(String, fmi3String)
NO_VARIABLES_SET(Float32, fmi3Float32)
NO_VARIABLES_SET(Int8, fmi3Int8)
NO_VARIABLES_SET(UInt8, fmi3UInt8)
NO_VARIABLES_SET(Int16, fmi3Int16)
NO_VARIABLES_SET(UInt16, fmi3UInt16)
NO_VARIABLES_SET(UInt32, fmi3UInt32)
NO_VARIABLES_SET(Int64, fmi3Int64)
NO_VARIABLES_SET(UInt64, fmi3UInt64)
NO_VARIABLES_SET(String, fmi3String)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, size_t valueSizes[], fmi3Binary values[], size_t nValues) {
    if (check_n(INSTANCE, nValueReferences, nValues, "fmi3GetBinary") != fmi3OK) return fmi3Error;
#ifdef FMU_BUS
    return status3(fmu_bus_get_binary(INSTANCE, valueReferences, nValueReferences, valueSizes, values));
#else
    (void)valueSizes, (void)values;
    return status3(fmu_no_variables_of_type(INSTANCE, "Binary", nValueReferences));
#endif
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, const size_t valueSizes[], const fmi3Binary values[],
                         size_t nValues) {
    if (check_n(INSTANCE, nValueReferences, nValues, "fmi3SetBinary") != fmi3OK) return fmi3Error;
#ifdef FMU_BUS
    return status3(fmu_bus_set_binary(INSTANCE, valueReferences, nValueReferences, valueSizes, values));
#else
    (void)valueSizes, (void)values;
    return status3(fmu_no_variables_of_type(INSTANCE, "Binary", nValueReferences));
#endif
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, fmi3Clock values[]) {
#ifdef FMU_BUS
    return status3(fmu_bus_get_clock(INSTANCE, valueReferences, nValueReferences, values));
#else
    (void)values;
    return status3(fmu_no_variables_of_type(INSTANCE, "Clock", nValueReferences));
#endif
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, const fmi3Clock values[]) {
#ifdef FMU_BUS
    return status3(fmu_bus_set_clock(INSTANCE, valueReferences, nValueReferences, values));
#else
    (void)values;
    return status3(fmu_no_variables_of_type(INSTANCE, "Clock", nValueReferences));
#endif
}

/* ---- 2.3.6 variable dependencies (not provided; the static ModelStructure is complete) ------------ */
fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    (void)valueReference, (void)nDependencies;
    return status3(fmu_unsupported(INSTANCE, "fmi3GetNumberOfVariableDependencies"));
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[], size_t nDependencies) {
    (void)dependent, (void)elementIndicesOfDependent, (void)independents, (void)elementIndicesOfIndependents;
    (void)dependencyKinds, (void)nDependencies;
    return status3(fmu_unsupported(INSTANCE, "fmi3GetVariableDependencies"));
}

/* ---- 2.3.7 FMU state ------------------------------------------------------------------------------ */
fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    return status3(fmu_get_state(INSTANCE, FMUState));
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    return status3(fmu_set_state(INSTANCE, FMUState));
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    return status3(fmu_free_state(INSTANCE, FMUState));
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size) {
    (void)FMUState;
    if (!instance) return fmi3Error;
    if (!size) return status3(fmu_unsupported(INSTANCE, "fmi3SerializedFMUStateSize with size == NULL"));
    *size = fmu_serialized_state_size();
    return fmi3OK;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                 size_t size) {
    return status3(fmu_serialize_state(INSTANCE, FMUState, serializedState, size));
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState *FMUState) {
    return status3(fmu_deserialize_state(INSTANCE, serializedState, size, FMUState));
}

/* ---- 2.3.8 partial derivatives (outputs by inputs, exact: fmu_model_jacobian) ---------------------- */
fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns,
                                        const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
                                        size_t nSensitivity) {
    return status3(fmu_derivatives(INSTANCE, unknowns, nUnknowns, knowns, nKnowns, seed, nSeed, sensitivity,
                                   nSensitivity, false, "fmi3GetDirectionalDerivative"));
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                    size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns,
                                    const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
                                    size_t nSensitivity) {
    return status3(fmu_derivatives(INSTANCE, unknowns, nUnknowns, knowns, nKnowns, seed, nSeed, sensitivity,
                                   nSensitivity, true, "fmi3GetAdjointDerivative"));
}

/* ---- 2.3.3 configuration mode (no structural parameters) ------------------------------------------- */
fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    return status3(fmu_unsupported(INSTANCE, "fmi3EnterConfigurationMode (no structural parameters)"));
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    return status3(fmu_unsupported(INSTANCE, "fmi3ExitConfigurationMode (no structural parameters)"));
}

/* ---- 2.3.9 clocks (none) ---------------------------------------------------------------------------- */
fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, fmi3Float64 intervals[],
                                  fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences, (void)nValueReferences, (void)intervals, (void)qualifiers;
    return status3(fmu_unsupported(INSTANCE, "fmi3GetIntervalDecimal (no clocks)"));
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences, (void)nValueReferences, (void)counters, (void)resolutions, (void)qualifiers;
    return status3(fmu_unsupported(INSTANCE, "fmi3GetIntervalFraction (no clocks)"));
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, fmi3Float64 shifts[]) {
    (void)valueReferences, (void)nValueReferences, (void)shifts;
    return status3(fmu_unsupported(INSTANCE, "fmi3GetShiftDecimal (no clocks)"));
}

fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[]) {
    (void)valueReferences, (void)nValueReferences, (void)counters, (void)resolutions;
    return status3(fmu_unsupported(INSTANCE, "fmi3GetShiftFraction (no clocks)"));
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, const fmi3Float64 intervals[]) {
    (void)valueReferences, (void)nValueReferences, (void)intervals;
    return status3(fmu_unsupported(INSTANCE, "fmi3SetIntervalDecimal (no clocks)"));
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, const fmi3UInt64 counters[],
                                   const fmi3UInt64 resolutions[]) {
    (void)valueReferences, (void)nValueReferences, (void)counters, (void)resolutions;
    return status3(fmu_unsupported(INSTANCE, "fmi3SetIntervalFraction (no clocks)"));
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, const fmi3Float64 shifts[]) {
    (void)valueReferences, (void)nValueReferences, (void)shifts;
    return status3(fmu_unsupported(INSTANCE, "fmi3SetShiftDecimal (no clocks)"));
}

fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, const fmi3UInt64 counters[],
                                const fmi3UInt64 resolutions[]) {
    (void)valueReferences, (void)nValueReferences, (void)counters, (void)resolutions;
    return status3(fmu_unsupported(INSTANCE, "fmi3SetShiftFraction (no clocks)"));
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    return status3(fmu_unsupported(INSTANCE, "fmi3EvaluateDiscreteStates (no event mode)"));
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged, fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
#ifdef FMU_BUS
    FmuStatus s = fmu_bus_update(INSTANCE);
    if (discreteStatesNeedUpdate) *discreteStatesNeedUpdate = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (nominalsOfContinuousStatesChanged) *nominalsOfContinuousStatesChanged = fmi3False;
    if (valuesOfContinuousStatesChanged) *valuesOfContinuousStatesChanged = fmi3False;
    if (nextEventTimeDefined) *nextEventTimeDefined = fmi3False;
    if (nextEventTime) *nextEventTime = 0.0;
    return status3(s);
#else
    (void)discreteStatesNeedUpdate, (void)terminateSimulation, (void)nominalsOfContinuousStatesChanged;
    (void)valuesOfContinuousStatesChanged, (void)nextEventTimeDefined, (void)nextEventTime;
    return status3(fmu_unsupported(INSTANCE, "fmi3UpdateDiscreteStates (no event mode)"));
#endif
}

/* ---- section 3 Model Exchange (not supported) ------------------------------------------------------ */
fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    return status3(fmu_unsupported(INSTANCE, "fmi3EnterContinuousTimeMode"));
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint, (void)enterEventMode, (void)terminateSimulation;
    return status3(fmu_unsupported(INSTANCE, "fmi3CompletedIntegratorStep"));
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    (void)time;
    return status3(fmu_unsupported(INSTANCE, "fmi3SetTime"));
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    (void)continuousStates, (void)nContinuousStates;
    return status3(fmu_unsupported(INSTANCE, "fmi3SetContinuousStates"));
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    (void)derivatives, (void)nContinuousStates;
    return status3(fmu_unsupported(INSTANCE, "fmi3GetContinuousStateDerivatives"));
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[], size_t nEventIndicators) {
    (void)eventIndicators, (void)nEventIndicators;
    return status3(fmu_unsupported(INSTANCE, "fmi3GetEventIndicators"));
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    (void)continuousStates, (void)nContinuousStates;
    return status3(fmu_unsupported(INSTANCE, "fmi3GetContinuousStates"));
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    (void)nominals, (void)nContinuousStates;
    return status3(fmu_unsupported(INSTANCE, "fmi3GetNominalsOfContinuousStates"));
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    (void)nEventIndicators;
    return status3(fmu_unsupported(INSTANCE, "fmi3GetNumberOfEventIndicators"));
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    (void)nContinuousStates;
    return status3(fmu_unsupported(INSTANCE, "fmi3GetNumberOfContinuousStates"));
}

/* ---- section 4 Co-Simulation ------------------------------------------------------------------------ */
fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
#ifdef FMU_BUS
    return status3(fmu_enter_step_mode(INSTANCE));
#else
    return status3(fmu_unsupported(INSTANCE, "fmi3EnterStepMode (no event mode: ExitInitializationMode "
                                             "enters Step Mode)"));
#endif
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Int32 orders[], fmi3Float64 values[],
                                    size_t nValues) {
    (void)valueReferences, (void)nValueReferences, (void)orders, (void)values, (void)nValues;
    return status3(fmu_unsupported(INSTANCE, "fmi3GetOutputDerivatives (maxOutputDerivativeOrder=\"0\")"));
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn,
                      fmi3Float64 *lastSuccessfulTime) {
    (void)noSetFMUStatePriorToCurrentPoint;
    if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (earlyReturn) *earlyReturn = fmi3False;
    FmuStatus s = fmu_do_step(INSTANCE, currentCommunicationPoint, communicationStepSize);
    if (lastSuccessfulTime && instance) *lastSuccessfulTime = INSTANCE->values.time;
#ifdef FMU_BUS
    /* a triggered Tx_Clock ticks at the end of the step when Tx data wait (FMI-LS-BUS 4.x, Tx Clocks) */
    if (eventHandlingNeeded && instance && s == FMU_OK)
        *eventHandlingNeeded = INSTANCE->event_mode_used && fmu_bus_pending(INSTANCE);
#endif
    return status3(s);
}

/* ---- section 5 Scheduled Execution (not supported) -------------------------------------------------- */
fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    (void)clockReference, (void)activationTime;
    return status3(fmu_unsupported(INSTANCE, "fmi3ActivateModelPartition"));
}
