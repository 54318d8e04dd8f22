/* step_fmi3.c -- a minimal FMI 3.0 Co-Simulation importer in C: loads a binary with dlopen, instantiates,
 * sets Float64 inputs to constant values, takes n steps of h and prints the requested Float64 outputs
 * (one per line, %.17g). Built for a foreign platform (zig cc -target aarch64-linux-gnu.2.17), it steps
 * that platform's binary under a user-mode emulator (qemu-aarch64), where no Python importer runs.
 *
 * usage: step_fmi3 BINARY TOKEN N_STEPS H VR=VALUE[,VR=VALUE...] VR[,VR...]
 * exit status: 0, 1 on a usage error, 2 when an FMI call fails (its status on stderr). */
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"

#define MAX_VARIABLES 64

static void *load(void *library, const char *name) {
    void *f = dlsym(library, name);
    if (!f) {
        fprintf(stderr, "%s not exported: %s\n", name, dlerror());
        exit(2);
    }
    return f;
}

static void check(fmi3Status status, const char *call) {
    if (status > fmi3Warning) {
        fprintf(stderr, "%s returned status %d\n", call, (int)status);
        exit(2);
    }
}

static size_t parse_list(char *text, fmi3ValueReference vr[], double value[]) {
    size_t n = 0;
    for (char *item = strtok(text, ","); item && n < MAX_VARIABLES; item = strtok(NULL, ",")) {
        char *eq = strchr(item, '=');
        vr[n] = (fmi3ValueReference)strtoul(item, NULL, 10);
        if (value) value[n] = eq ? strtod(eq + 1, NULL) : 0.0;
        n++;
    }
    return n;
}

int main(int argc, char **argv) {
    if (argc != 7) {
        fprintf(stderr, "usage: %s BINARY TOKEN N_STEPS H VR=VALUE[,...] VR[,...]\n", argv[0]);
        return 1;
    }
    void *library = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!library) {
        fprintf(stderr, "cannot load %s: %s\n", argv[1], dlerror());
        return 2;
    }
    fmi3InstantiateCoSimulationTYPE *instantiate = load(library, "fmi3InstantiateCoSimulation");
    fmi3EnterInitializationModeTYPE *enter = load(library, "fmi3EnterInitializationMode");
    fmi3ExitInitializationModeTYPE *exit_init = load(library, "fmi3ExitInitializationMode");
    fmi3SetFloat64TYPE *set = load(library, "fmi3SetFloat64");
    fmi3GetFloat64TYPE *get = load(library, "fmi3GetFloat64");
    fmi3DoStepTYPE *step = load(library, "fmi3DoStep");
    fmi3TerminateTYPE *terminate = load(library, "fmi3Terminate");
    fmi3FreeInstanceTYPE *free_instance = load(library, "fmi3FreeInstance");
    long n = strtol(argv[3], NULL, 10);
    double h = strtod(argv[4], NULL), in_value[MAX_VARIABLES], out_value[MAX_VARIABLES];
    fmi3ValueReference in_vr[MAX_VARIABLES], out_vr[MAX_VARIABLES];
    size_t n_in = parse_list(argv[5], in_vr, in_value), n_out = parse_list(argv[6], out_vr, NULL);
    fmi3Instance instance = instantiate("harness", argv[2], NULL, fmi3False, fmi3False, fmi3False, fmi3False,
                                       NULL, 0, NULL, NULL, NULL);
    if (!instance) {
        fprintf(stderr, "fmi3InstantiateCoSimulation returned NULL\n");
        return 2;
    }
    check(enter(instance, fmi3False, 0.0, 0.0, fmi3False, 0.0), "fmi3EnterInitializationMode");
    check(exit_init(instance), "fmi3ExitInitializationMode");
    check(set(instance, in_vr, n_in, in_value, n_in), "fmi3SetFloat64");
    double t = 0.0;
    for (long i = 0; i < n; i++) {
        fmi3Boolean event = fmi3False, terminate_now = fmi3False, early = fmi3False;
        double last = 0.0;
        check(step(instance, t, h, fmi3True, &event, &terminate_now, &early, &last), "fmi3DoStep");
        t += h;
    }
    check(get(instance, out_vr, n_out, out_value, n_out), "fmi3GetFloat64");
    for (size_t j = 0; j < n_out; j++) printf("%.17g\n", out_value[j]);
    check(terminate(instance), "fmi3Terminate");
    free_instance(instance);
    dlclose(library);
    return 0;
}
