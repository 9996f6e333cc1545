/* lc-mesh twin: FMI 2.0 co-simulation interface around lcmesh_model.c.
 * Every variable is a Real addressed by its value reference (an index into Model.r). */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "lcmesh_model.h"

#define STATE_MAGIC 0x4c434d53u /* "LCMS" */

enum Phase { INSTANTIATED, INITIALIZATION, STEPPING, TERMINATED, FAILED };

typedef struct {
    Model model;
    fmi2CallbackFunctions callbacks;
    char name[128];
    int phase;
    int logging;
} Instance;

typedef struct {
    unsigned magic;
    unsigned long long size;
    Model model;
} SavedState;

static void log_error(Instance *inst, const char *fmt, ...) {
    if (!inst || !inst->callbacks.logger) return;
    char buf[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    inst->callbacks.logger(inst->callbacks.componentEnvironment, inst->name, fmi2Error, "error", "%s", buf);
}

static void load_start_values(Instance *inst) {
    memcpy(inst->model.r, START_VALUES, sizeof(double) * N_REALS);
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String categories[]) {
    (void)n;
    (void)categories;
    ((Instance *)c)->logging = on;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String location,
                              const fmi2CallbackFunctions *callbacks, fmi2Boolean visible, fmi2Boolean logging) {
    (void)location;
    (void)visible;
    if (type != fmi2CoSimulation) return NULL;
    if (guid && strcmp(guid, MODEL_GUID) != 0) {
        if (callbacks && callbacks->logger)
            callbacks->logger(callbacks->componentEnvironment, name, fmi2Error, "error",
                              "GUID mismatch: expected %s, got %s", MODEL_GUID, guid);
        return NULL;
    }
    Instance *inst = calloc(1, sizeof(Instance));
    if (!inst) return NULL;
    if (callbacks) inst->callbacks = *callbacks;
    snprintf(inst->name, sizeof inst->name, "%s", name ? name : "lcmesh");
    inst->logging = logging;
    inst->phase = INSTANTIATED;
    load_start_values(inst);
    return inst;
}

void fmi2FreeInstance(fmi2Component c) { free(c); }

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tol_defined, fmi2Real tol, fmi2Real start,
                               fmi2Boolean stop_defined, fmi2Real stop) {
    (void)tol_defined;
    (void)tol;
    (void)stop_defined;
    (void)stop;
    ((Instance *)c)->model.time = start;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    ((Instance *)c)->phase = INITIALIZATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Instance *inst = c;
    double start = inst->model.time;
    model_init(&inst->model);
    inst->model.time = start;
    model_outputs_at_init(&inst->model);
    inst->phase = STEPPING;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    ((Instance *)c)->phase = TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    Instance *inst = c;
    memset(&inst->model, 0, sizeof(Model));
    load_start_values(inst);
    inst->phase = INSTANTIATED;
    return fmi2OK;
}

static int check_refs(Instance *inst, const fmi2ValueReference vr[], size_t n) {
    for (size_t i = 0; i < n; i++) {
        if (vr[i] >= N_REALS) {
            log_error(inst, "value reference %u out of range (model has %d reals)", vr[i], N_REALS);
            return 0;
        }
    }
    return 1;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    Instance *inst = c;
    if (!check_refs(inst, vr, n)) return fmi2Error;
    const double *r = inst->model.r;
    for (size_t i = 0; i < n; i++) value[i] = r[vr[i]];
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    Instance *inst = c;
    if (!check_refs(inst, vr, n)) return fmi2Error;
    double *r = inst->model.r;
    for (size_t i = 0; i < n; i++) r[vr[i]] = value[i];
    return fmi2OK;
}

static fmi2Status no_such_variables(fmi2Component c, size_t n, const char *type) {
    if (n == 0) return fmi2OK;
    log_error(c, "the model has no %s variables", type);
    return fmi2Error;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer value[]) {
    (void)vr;
    (void)value;
    return no_such_variables(c, n, "Integer");
}
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean value[]) {
    (void)vr;
    (void)value;
    return no_such_variables(c, n, "Boolean");
}
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String value[]) {
    (void)vr;
    (void)value;
    return no_such_variables(c, n, "String");
}
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer value[]) {
    (void)vr;
    (void)value;
    return no_such_variables(c, n, "Integer");
}
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean value[]) {
    (void)vr;
    (void)value;
    return no_such_variables(c, n, "Boolean");
}
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String value[]) {
    (void)vr;
    (void)value;
    return no_such_variables(c, n, "String");
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) {
    Instance *inst = c;
    SavedState *saved = *state ? (SavedState *)*state : malloc(sizeof(SavedState));
    if (!saved) return fmi2Error;
    saved->magic = STATE_MAGIC;
    saved->size = sizeof(Model);
    saved->model = inst->model;
    *state = saved;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    Instance *inst = c;
    const SavedState *saved = state;
    if (!saved || saved->magic != STATE_MAGIC || saved->size != sizeof(Model)) {
        log_error(inst, "not a state of this model");
        return fmi2Error;
    }
    inst->model = saved->model;
    inst->phase = STEPPING;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    (void)c;
    free(*state);
    *state = NULL;
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size) {
    (void)c;
    (void)state;
    *size = sizeof(SavedState) + sizeof(MODEL_GUID);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte bytes[], size_t size) {
    if (size < sizeof(SavedState) + sizeof(MODEL_GUID)) {
        log_error(c, "serialization buffer too small");
        return fmi2Error;
    }
    memcpy(bytes, MODEL_GUID, sizeof(MODEL_GUID));
    memcpy(bytes + sizeof(MODEL_GUID), state, sizeof(SavedState));
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size, fmi2FMUstate *state) {
    if (size != sizeof(SavedState) + sizeof(MODEL_GUID) || memcmp(bytes, MODEL_GUID, sizeof(MODEL_GUID)) != 0) {
        log_error(c, "serialized state is not from this model (size %zu)", size);
        return fmi2Error;
    }
    SavedState *saved = malloc(sizeof(SavedState));
    if (!saved) return fmi2Error;
    memcpy(saved, bytes + sizeof(MODEL_GUID), sizeof(SavedState));
    if (saved->magic != STATE_MAGIC || saved->size != sizeof(Model)) {
        free(saved);
        log_error(c, "serialized state is corrupt");
        return fmi2Error;
    }
    *state = saved;
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz, const fmi2Real du[],
                                        fmi2Real dz[]) {
    (void)u;
    (void)nu;
    (void)z;
    (void)nz;
    (void)du;
    (void)dz;
    log_error(c, "directional derivatives are not provided");
    return fmi2Error;
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr;
    (void)n;
    (void)order;
    (void)value;
    log_error(c, "input derivatives are not supported");
    return fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr;
    (void)n;
    (void)order;
    (void)value;
    log_error(c, "output derivatives are not supported");
    return fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean no_set_prior) {
    (void)t;
    (void)no_set_prior;
    Instance *inst = c;
    if (inst->phase != STEPPING) {
        log_error(inst, "fmi2DoStep called before initialization finished");
        return fmi2Error;
    }
    if (!(h > 0.0)) {
        log_error(inst, "communication step size must be > 0, got %g", h);
        return fmi2Error;
    }
    if (model_do_step(&inst->model, h) != 0) {
        inst->phase = FAILED;
        log_error(inst, "the state became non-finite at t = %g s", inst->model.time);
        return fmi2Error;
    }
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    (void)c;
    return fmi2OK;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)c;
    (void)s;
    *value = fmi2OK;
    return fmi2OK;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    if (s == fmi2LastSuccessfulTime) {
        *value = ((Instance *)c)->model.time;
        return fmi2OK;
    }
    return fmi2Discard;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)c;
    (void)s;
    (void)value;
    return fmi2Discard;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    (void)c;
    if (s == fmi2Terminated) {
        *value = fmi2False;
        return fmi2OK;
    }
    return fmi2Discard;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)c;
    (void)s;
    (void)value;
    return fmi2Discard;
}
