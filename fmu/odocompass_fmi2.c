/* OdoCompass native FMU: the FMI 2.0 co-simulation C API around the estimator step that
 * fmu/jaxpr_lower.py generates from the jaxpr of jaxmodel.run_from (issue 12).
 *
 * Hand-written and model-independent: everything about the model (variables, value references,
 * parameter layout, state size, configurations, validation) comes from the generated
 * odocompass_model.h and the generated C files beside it.  No Python, libc and libm only.
 *
 * One fmi2DoStep(t, h) processes ONE sensor sample: the inputs present at the call, stamped t + h.
 * A bad sample (non-finite compass, non-finite map heading/fix flagged valid, an implausible
 * counter jump, a step that does not advance time) is skipped with the state unchanged, counted in
 * discarded_samples, logged, and answered fmi2Warning: the co-simulation goes on.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "odocompass_fmi2.h"

/* ---------------------------------------------------------------------------------------- */
void *odc_alloc(const odc_inst *c, size_t n)
{
    if (c && c->cb.allocateMemory) return c->cb.allocateMemory(1, n);
    return calloc(1, n);
}

void odc_free(const odc_inst *c, void *ptr)
{
    if (!ptr) return;
    if (c && c->cb.freeMemory) c->cb.freeMemory(ptr);
    else free(ptr);
}

static int category_index(const char *category)
{
    int i;
    for (i = 0; i < ODC_N_CATEGORIES; i++)
        if (strcmp(ODC_CATEGORIES[i], category) == 0) return i;
    return -1;
}

/* The logger's message is a printf format: the text itself is passed with '%' doubled and no arguments, so hosts
 * that print it without formatting (ctypes callbacks) see it whole.  out holds at least 2 * strlen(in) + 1. */
static void escape_percent(const char *in, char *out, size_t size)
{
    char *end = out + size - 2;
    for (; *in && out < end; in++) {
        if (*in == '%') *out++ = '%';
        *out++ = *in;
    }
    *out = '\0';
}

/* fmi2OK messages need logging on and their category (or logAll) enabled; warnings and errors
 * are always reported. */
void odc_log(odc_inst *c, fmi2Status status, const char *category, const char *fmt, ...)
{
    va_list ap;
    if (!c->cb.logger) return;
    if (status == fmi2OK) {
        int i = category_index(category), all = category_index("logAll");
        if (!c->logging_on || !((i >= 0 && c->category_on[i]) || (all >= 0 && c->category_on[all]))) return;
    }
    va_start(ap, fmt);
    vsnprintf(c->text, sizeof c->text, fmt, ap);
    va_end(ap);
    escape_percent(c->text, c->msg, sizeof c->msg);
    c->cb.logger(c->cb.componentEnvironment, c->name, status, category, c->msg);
}

static void set_defaults(odc_dyn *d)
{
    int vr;
    memset(d, 0, sizeof *d);
    d->config = -1;
    d->t_last = -INFINITY;
    for (vr = 0; vr < ODC_N_VARS; vr++) {
        const odc_var *v = &ODC_VARS[vr];
        switch (v->group) {
        case 'x': d->x[v->slot] = v->start; break;
        case 'o': d->o[v->slot] = NAN; break;
        case 'p': if (v->type != 'S') d->p[v->slot] = v->start; else strcpy(d->str[v->slot], v->sstart); break;
        case 'c': if (v->type == 'S') strcpy(d->str[v->slot], v->sstart); else d->cfg_bool[v->slot] = v->start != 0.0; break;
        default: break;
        }
    }
}

/* ---------------------------------------------------------------------------------------- */
/* parameters: strings to numbers, validation, configuration                                   */
/* ---------------------------------------------------------------------------------------- */
static int apply_string_parameters(odc_inst *c, char *msg, size_t n)
{
    int i, k, bad = 0;
    for (i = 0; i < ODC_N_STRPARS; i++) {
        const odc_strpar *sp = &ODC_STRPARS[i];
        const char *value = c->d.str[sp->str_slot];
        for (k = 0; k < sp->n; k++)
            if (strcmp(value, sp->names[k]) == 0) { c->d.p[sp->flat] = sp->values[k]; break; }
        if (k == sp->n) {
            size_t used = strlen(msg);
            snprintf(msg + used, n - used, "%s%s=\"%s\" must be one of %s", used ? "; " : "", sp->key, value, sp->allowed);
            bad++;
        }
    }
    return bad;
}

static int find_config(odc_inst *c, char *msg, size_t n)
{
    char key[512] = "";
    int i;
    for (i = 0; i < ODC_N_CONFIG_PARTS; i++) {
        const odc_cfgpart *part = &ODC_CONFIG_PARTS[i];
        size_t used = strlen(key);
        if (part->type == 'S')
            snprintf(key + used, sizeof key - used, "%s=%s;", part->name, c->d.str[part->slot]);
        else
            snprintf(key + used, sizeof key - used, "%s=%d;", part->name, c->d.cfg_bool[part->slot] ? 1 : 0);
    }
    for (i = 0; i < ODC_N_CONFIGS; i++)
        if (strcmp(key, ODC_CONFIGS[i].key) == 0) return i;
    {
        size_t used = strlen(msg);
        snprintf(msg + used, n - used, "%sconfiguration %s is not one of this FMU's (%s)", used ? "; " : "", key,
                 ODC_CONFIG_CHOICES);
    }
    return -1;
}

/* Validate, pick the configuration, start the filter and process the initial sample. */
static fmi2Status initialize(odc_inst *c, int log_errors)
{
    char msg[2048] = "";
    int bad = apply_string_parameters(c, msg, sizeof msg);
    int config;
    const char *engine = c->d.str[ODC_STR_ENGINE];
    bad += odc_validate(c->d.p, msg, sizeof msg);
    config = find_config(c, msg, sizeof msg);
    if (strcmp(engine, "auto") && strcmp(engine, "native") && strcmp(engine, "python") && strcmp(engine, "xla")) {
        size_t used = strlen(msg);
        snprintf(msg + used, sizeof msg - used, "%sengine=\"%s\" must be one of auto, native, python, xla",
                 used ? "; " : "", engine);
        bad++;
    }
    if (bad || config < 0) {
        if (log_errors) odc_log(c, fmi2Error, "logBadParameter", "parameters refused: invalid parameters: %s", msg);
        c->d.outputs_valid = 0;
        return fmi2Error;
    }
    c->d.config = config;
    ODC_CONFIGS[config].init(c->d.p, c->d.s[0]);
    c->d.x[ODC_X_TIME] = c->d.t_start;
    ODC_CONFIGS[config].step(c->d.p, c->d.s[0], c->d.x, c->d.s[1], c->d.o);
    c->d.cur = 1;
    c->d.outputs_valid = 1;
    return fmi2OK;
}

static fmi2Status outputs_ready(odc_inst *c)
{
    if (c->d.outputs_valid) return fmi2OK;
    if (c->d.phase == PH_INIT || c->d.phase == PH_INSTANTIATED) return initialize(c, 1);
    return fmi2Error;
}

/* ---------------------------------------------------------------------------------------- */
/* FMI 2.0: common functions                                                                    */
/* ---------------------------------------------------------------------------------------- */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn)
{
    odc_inst *c;
    int i;
    (void)fmuResourceLocation; (void)visible;
    if (!functions || !functions->logger) return NULL;
    if (fmuType != fmi2CoSimulation) {
        functions->logger(functions->componentEnvironment, instanceName, fmi2Error, "logStatusError",
                          "OdoCompass supports co-simulation only");
        return NULL;
    }
    if (!fmuGUID || strcmp(fmuGUID, ODC_GUID) != 0) {
        char text[512], msg[1024];  /* formatted here as odc_log does: there is no instance yet */
        snprintf(text, sizeof text, "GUID %s does not match this binary (%s)", fmuGUID ? fmuGUID : "(null)", ODC_GUID);
        escape_percent(text, msg, sizeof msg);
        functions->logger(functions->componentEnvironment, instanceName, fmi2Error, "logStatusError", msg);
        return NULL;
    }
    c = functions->allocateMemory ? (odc_inst *)functions->allocateMemory(1, sizeof *c) : (odc_inst *)calloc(1, sizeof *c);
    if (!c) return NULL;
    memset(c, 0, sizeof *c);
    c->cb = *functions;
    snprintf(c->name, sizeof c->name, "%s", instanceName ? instanceName : "OdoCompass");
    c->logging_on = loggingOn ? 1 : 0;
    for (i = 0; i < ODC_N_CATEGORIES; i++) c->category_on[i] = 1;
    set_defaults(&c->d);
    odc_log(c, fmi2OK, "logEngine", "instantiated (%d configurations compiled, %d parameters, %d state values)",
            ODC_N_CONFIGS, ODC_N_PARAM, ODC_N_STATE);
    return c;
}

void fmi2FreeInstance(fmi2Component comp)
{
    odc_inst *c = (odc_inst *)comp;
    if (c) {
        fmi2CallbackFunctions cb = c->cb;
        if (cb.freeMemory) cb.freeMemory(c);
        else free(c);
    }
}

fmi2Status fmi2SetDebugLogging(fmi2Component comp, fmi2Boolean loggingOn, size_t n, const fmi2String categories[])
{
    odc_inst *c = (odc_inst *)comp;
    size_t k;
    int i;
    if (!c) return fmi2Error;
    c->logging_on = loggingOn ? 1 : 0;
    if (n == 0) {
        for (i = 0; i < ODC_N_CATEGORIES; i++) c->category_on[i] = 1;
        return fmi2OK;
    }
    for (i = 0; i < ODC_N_CATEGORIES; i++) c->category_on[i] = 0;
    for (k = 0; k < n; k++) {
        i = categories[k] ? category_index(categories[k]) : -1;
        if (i < 0) {
            odc_log(c, fmi2Error, "logStatusError", "fmi2SetDebugLogging: unknown log category %s",
                    categories[k] ? categories[k] : "(null)");
            return fmi2Error;
        }
        c->category_on[i] = 1;
    }
    return fmi2OK;
}

fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    odc_inst *c = (odc_inst *)comp;
    (void)toleranceDefined; (void)tolerance; (void)stopTimeDefined; (void)stopTime;
    if (!c) return fmi2Error;
    if (c->d.phase != PH_INSTANTIATED) {
        odc_log(c, fmi2Error, "logStatusError", "fmi2SetupExperiment: only after fmi2Instantiate");
        return fmi2Error;
    }
    if (!isfinite(startTime)) {
        odc_log(c, fmi2Error, "logBadStep", "fmi2SetupExperiment: start time %g is not finite", startTime);
        return fmi2Error;
    }
    c->d.t_start = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component comp)
{
    odc_inst *c = (odc_inst *)comp;
    if (!c) return fmi2Error;
    if (c->d.phase != PH_INSTANTIATED) {
        odc_log(c, fmi2Error, "logStatusError", "fmi2EnterInitializationMode: only after fmi2Instantiate");
        return fmi2Error;
    }
    c->d.phase = PH_INIT;
    c->d.outputs_valid = 0;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component comp)
{
    odc_inst *c = (odc_inst *)comp;
    fmi2Status st;
    if (!c) return fmi2Error;
    if (c->d.phase != PH_INIT) {
        odc_log(c, fmi2Error, "logStatusError", "fmi2ExitInitializationMode: not in initialization mode");
        return fmi2Error;
    }
    st = c->d.outputs_valid ? fmi2OK : initialize(c, 1);
    if (st != fmi2OK) return st;
    c->d.phase = PH_STEPPING;
    c->d.t_last = c->d.t_start;
    c->d.strikes = 0;
    memset(c->d.stop_running, 0, sizeof c->d.stop_running);
    memset(c->d.stop_reported, 0, sizeof c->d.stop_reported);
    if (!(isfinite(c->d.x[ODC_X_CX]) && isfinite(c->d.x[ODC_X_CY])))
        odc_log(c, fmi2Warning, "logBadInput", "initial sample: non-finite compass reading (compass_x=%g, "
                "compass_y=%g); the estimator skips it", c->d.x[ODC_X_CX], c->d.x[ODC_X_CY]);
    odc_log(c, fmi2OK, "logEngine", "initialized: configuration %s", ODC_CONFIGS[c->d.config].key);
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component comp)
{
    odc_inst *c = (odc_inst *)comp;
    if (!c) return fmi2Error;
    c->d.phase = PH_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component comp)
{
    odc_inst *c = (odc_inst *)comp;
    if (!c) return fmi2Error;
    set_defaults(&c->d);
    return fmi2OK;
}

/* ---------------------------------------------------------------------------------------- */
/* variable access                                                                               */
/* ---------------------------------------------------------------------------------------- */
static const odc_var *lookup(odc_inst *c, fmi2ValueReference vr, char type, const char *fn)
{
    const odc_var *v;
    if (vr >= (fmi2ValueReference)ODC_N_VARS) {
        odc_log(c, fmi2Error, "logBadParameter", "%s: unknown value reference %u", fn, (unsigned)vr);
        return NULL;
    }
    v = &ODC_VARS[vr];
    if (v->type != type) {
        odc_log(c, fmi2Error, "logBadParameter", "%s: %s (value reference %u) is not of this type", fn, v->name,
                (unsigned)vr);
        return NULL;
    }
    return v;
}

static int settable(odc_inst *c, const odc_var *v, const char *fn)
{
    if (v->group == 'o' || v->group == 'd') {
        odc_log(c, fmi2Error, "logBadParameter", "%s: %s is an output and cannot be set", fn, v->name);
        return 0;
    }
    if ((v->group == 'p' || v->group == 'c') && c->d.phase != PH_INSTANTIATED && c->d.phase != PH_INIT) {
        odc_log(c, fmi2Error, "logBadParameter", "%s: parameter %s is fixed after initialization", fn, v->name);
        return 0;
    }
    if (c->d.phase == PH_INSTANTIATED || c->d.phase == PH_INIT) c->d.outputs_valid = 0;
    return 1;
}

fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    odc_inst *c = (odc_inst *)comp;
    size_t i;
    if (!c) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const odc_var *v = lookup(c, vr[i], 'R', "fmi2GetReal");
        if (!v) return fmi2Error;
        if (v->group == 'o') {
            if (outputs_ready(c) != fmi2OK) return fmi2Error;
            value[i] = c->d.o[v->slot];
        } else if (v->group == 'x') {
            value[i] = c->d.x[v->slot];
        } else {
            value[i] = c->d.p[v->slot];
        }
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[])
{
    odc_inst *c = (odc_inst *)comp;
    size_t i;
    if (!c) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const odc_var *v = lookup(c, vr[i], 'I', "fmi2GetInteger");
        if (!v) return fmi2Error;
        if (v->group == 'd') value[i] = c->d.discarded;
        else if (v->group == 'x') value[i] = (fmi2Integer)c->d.x[v->slot];
        else value[i] = (fmi2Integer)c->d.p[v->slot];
    }
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[])
{
    odc_inst *c = (odc_inst *)comp;
    size_t i;
    if (!c) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const odc_var *v = lookup(c, vr[i], 'B', "fmi2GetBoolean");
        if (!v) return fmi2Error;
        if (v->group == 'o') {
            if (outputs_ready(c) != fmi2OK) return fmi2Error;
            value[i] = c->d.o[v->slot] != 0.0 ? fmi2True : fmi2False;
        } else if (v->group == 'x') {
            value[i] = c->d.x[v->slot] != 0.0 ? fmi2True : fmi2False;
        } else {
            value[i] = c->d.cfg_bool[v->slot] ? fmi2True : fmi2False;
        }
    }
    return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2String value[])
{
    odc_inst *c = (odc_inst *)comp;
    size_t i;
    if (!c) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const odc_var *v = lookup(c, vr[i], 'S', "fmi2GetString");
        if (!v) return fmi2Error;
        value[i] = c->d.str[v->slot];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[])
{
    odc_inst *c = (odc_inst *)comp;
    size_t i;
    if (!c) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const odc_var *v = lookup(c, vr[i], 'R', "fmi2SetReal");
        if (!v || !settable(c, v, "fmi2SetReal")) return fmi2Error;
        if (v->group == 'x') c->d.x[v->slot] = value[i];
        else c->d.p[v->slot] = value[i];
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[])
{
    odc_inst *c = (odc_inst *)comp;
    size_t i;
    if (!c) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const odc_var *v = lookup(c, vr[i], 'I', "fmi2SetInteger");
        if (!v || !settable(c, v, "fmi2SetInteger")) return fmi2Error;
        if (v->group == 'x') c->d.x[v->slot] = (double)value[i];
        else c->d.p[v->slot] = (double)value[i];
    }
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[])
{
    odc_inst *c = (odc_inst *)comp;
    size_t i;
    if (!c) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const odc_var *v = lookup(c, vr[i], 'B', "fmi2SetBoolean");
        if (!v || !settable(c, v, "fmi2SetBoolean")) return fmi2Error;
        if (v->group == 'x') c->d.x[v->slot] = value[i] ? 1.0 : 0.0;
        else c->d.cfg_bool[v->slot] = value[i] ? 1 : 0;
    }
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[])
{
    odc_inst *c = (odc_inst *)comp;
    size_t i;
    if (!c) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const odc_var *v = lookup(c, vr[i], 'S', "fmi2SetString");
        if (!v || !settable(c, v, "fmi2SetString")) return fmi2Error;
        if (!value[i] || strlen(value[i]) >= ODC_STRLEN) {
            odc_log(c, fmi2Error, "logBadParameter", "fmi2SetString: value of %s missing or longer than %d characters",
                    v->name, ODC_STRLEN - 1);
            return fmi2Error;
        }
        strcpy(c->d.str[v->slot], value[i]);
    }
    return fmi2OK;
}

/* ---------------------------------------------------------------------------------------- */
/* stepping                                                                                      */
/* ---------------------------------------------------------------------------------------- */
static fmi2Status refuse(odc_inst *c, const char *category, const char *problem, double t_sample)
{
    c->d.discarded++;
    odc_log(c, fmi2Warning, category, "%s at t=%.17g s: sample skipped, estimator state unchanged "
            "(discarded_samples=%d)", problem, t_sample, c->d.discarded);
    return fmi2Warning;
}

/* (left, right) pulses of the sample in x since the current state's last counts, wraps decoded as jaxmodel does
 * (the twin of OdoCompass._increments). */
static void counter_increments(const odc_dyn *d, double inc[2])
{
    const double mod = d->p[ODC_P_COUNTER_MODULUS];
    const double *s = d->s[d->cur];
    int i;
    inc[0] = d->x[ODC_X_LEFT] - s[ODC_S_LAST_LEFT];
    inc[1] = d->x[ODC_X_RIGHT] - s[ODC_S_LAST_RIGHT];
    for (i = 0; i < 2; i++) inc[i] -= mod * nearbyint(inc[i] / mod);
}

static void counter_message(odc_inst *c, char *buf, size_t n, double t_sample)
{
    double inc[2];
    counter_increments(&c->d, inc);
    snprintf(buf, n, "implausible pulse counter jump (left %+.0f, right %+.0f counts in %.6g s, beyond max_speed=%g m/s)",
             inc[0], inc[1], t_sample - c->d.t_last, c->d.p[ODC_P_MAX_SPEED]);
}

/* A wheel counter that stopped counting while the other counted on (a sensor fault): reported once it lasts
 * ODC_STOPPED_MIN_S (a warning), and its end (information).  The twin of fmi_support.StoppedCounterWatch (the
 * pythonfmu FMU); the thresholds are jaxmodel.plausibility's, generated into odocompass_model.h.  Called for a
 * stepped sample before cur and t_last move on (d->s[d->cur] is the state before the sample).  Returns status, or
 * fmi2Warning. */
static fmi2Status watch_counters(odc_inst *c, double t_sample, fmi2Status status)
{
    static const char *const side[2] = {"left", "right"};
    odc_dyn *d = &c->d;
    double inc[2];
    int i;
    if (!(d->s[d->cur][ODC_S_STARTED] > 0.5)) return status;
    counter_increments(d, inc);
    for (i = 0; i < 2; i++) {
        if (inc[i] == 0.0 && fabs(inc[1 - i]) >= ODC_STOPPED_OTHER_PULSES) {
            if (!d->stop_running[i]) {
                d->stop_running[i] = 1;
                d->stop_since[i] = d->t_last;
            }
            if (!d->stop_reported[i] && t_sample - d->stop_since[i] >= ODC_STOPPED_MIN_S) {
                d->stop_reported[i] = 1;
                odc_log(c, fmi2Warning, "logBadInput", "%s_pulses stopped counting while %s_pulses counted on, since "
                        "t=%.17g s: a wheel sensor fault; the estimator replaces its samples by the other wheel's "
                        "travel where it can tell them from a turn", side[i], side[1 - i], d->stop_since[i]);
                status = fmi2Warning;
            }
            continue;
        }
        if (d->stop_reported[i])
            odc_log(c, fmi2OK, "logBadInput", "%s_pulses no longer stopped at t=%.17g s (stopped since t=%.17g s, "
                    "%.6g s)", side[i], t_sample, d->stop_since[i], d->t_last - d->stop_since[i]);
        d->stop_running[i] = d->stop_reported[i] = 0;
    }
    return status;
}

fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real t, fmi2Real h, fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    odc_inst *c = (odc_inst *)comp;
    odc_dyn *d;
    double t_sample, *x;
    const double *s;
    double *s_new, *o_new;
    char problem[512];
    int has_problem = 0, discard;
    fmi2Status status = fmi2OK;
    double o_tmp[ODC_N_OUT];
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!c) return fmi2Error;
    d = &c->d;
    if (d->phase != PH_STEPPING) {
        odc_log(c, fmi2Error, "logStatusError", "fmi2DoStep: not initialized (or terminated)");
        return fmi2Error;
    }
    discard = d->cfg_bool[ODC_BOOL_DISCARD];
    t_sample = t + h;
    if (!(h > 0.0 && h < INFINITY)) {
        snprintf(problem, sizeof problem, "communication step size h=%g at t=%.17g s: must be positive and finite", h, t);
        return refuse(c, "logBadStep", problem, t_sample);
    }
    if (!(t_sample > d->t_last)) {
        snprintf(problem, sizeof problem, "sample time t+h=%.17g s does not advance past the last sample (%.17g s)",
                 t_sample, d->t_last);
        return refuse(c, "logBadStep", problem, t_sample);
    }
    x = d->x;
    x[ODC_X_TIME] = t_sample;
    if (!(isfinite(x[ODC_X_CX]) && isfinite(x[ODC_X_CY]))) {
        snprintf(problem, sizeof problem, "non-finite compass reading (compass_x=%g, compass_y=%g)", x[ODC_X_CX], x[ODC_X_CY]);
        has_problem = 1;
    } else if ((x[ODC_X_MAP_VALID] > 0.5 && !isfinite(x[ODC_X_MAP])) ||
               (x[ODC_X_FIX_VALID] > 0.5 && !(isfinite(x[ODC_X_FE]) && isfinite(x[ODC_X_FN])))) {
        snprintf(problem, sizeof problem, "non-finite map heading or position fix flagged valid (map_heading=%g, "
                 "fix_east_m=%g, fix_north_m=%g)", x[ODC_X_MAP], x[ODC_X_FE], x[ODC_X_FN]);
        has_problem = 1;
    }
    if (has_problem && discard) return refuse(c, "logBadInput", problem, t_sample);
    s = d->s[d->cur];
    s_new = d->s[1 - d->cur];
    o_new = o_tmp;
    ODC_CONFIGS[d->config].step(d->p, s, x, s_new, o_new);
    if (o_new[ODC_O_ODOMETER_VALID] == 0.0 && s[ODC_S_STARTED] > 0.5) {
        char counters[384];
        counter_message(c, counters, sizeof counters, t_sample);
        if (d->strikes == 0 && !has_problem) {
            d->strikes = 1;
            if (discard) return refuse(c, "logBadInput", counters, t_sample);
            memcpy(problem, counters, sizeof counters);
            has_problem = 1;
        } else {
            d->strikes = 0;
            odc_log(c, fmi2Warning, "logBadInput", "%s, again: accepted as a counter reset at t=%.17g s (that "
                    "sample's distance dropped, counters re-synchronised)", counters, t_sample);
            status = fmi2Warning;
        }
    } else {
        d->strikes = 0;
    }
    if (has_problem) {
        d->discarded++;
        odc_log(c, fmi2Warning, "logBadInput", "%s at t=%.17g s: passed to the estimator, which skips what is "
                "unusable (discard_bad_samples=false)", problem, t_sample);
        status = fmi2Warning;
    }
    status = watch_counters(c, t_sample, status);
    d->cur = 1 - d->cur;
    memcpy(d->o, o_new, sizeof d->o);
    d->t_last = t_sample;
    return status;
}

