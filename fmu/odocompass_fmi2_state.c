/* OdoCompass native FMU: FMU state (get/set/serialize), status inquiry and the functions this FMU
 * does not provide (issue 12).  Hand-written and model-independent; see odocompass_fmi2.c. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "odocompass_fmi2.h"


fmi2Status fmi2CancelStep(fmi2Component comp)
{
    odc_inst *c = (odc_inst *)comp;
    if (c) odc_log(c, fmi2Error, "logStatusError", "fmi2CancelStep: steps are never asynchronous here");
    return fmi2Error;
}

fmi2Status fmi2GetStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Status *value)
{
    (void)comp;
    if (s == fmi2DoStepStatus && value) { *value = fmi2OK; return fmi2OK; }
    return fmi2Discard;
}

fmi2Status fmi2GetRealStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Real *value)
{
    odc_inst *c = (odc_inst *)comp;
    if (c && s == fmi2LastSuccessfulTime && value) { *value = c->d.t_last; return fmi2OK; }
    return fmi2Discard;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Integer *value)
{
    (void)comp; (void)s; (void)value;
    return fmi2Discard;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Boolean *value)
{
    (void)comp;
    if (s == fmi2Terminated && value) { *value = fmi2False; return fmi2OK; } /* a bad sample never ends the run */
    return fmi2Discard;
}

fmi2Status fmi2GetStringStatus(fmi2Component comp, const fmi2StatusKind s, fmi2String *value)
{
    (void)comp; (void)s; (void)value;
    return fmi2Discard;
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    odc_inst *c = (odc_inst *)comp;
    (void)vr; (void)nvr; (void)order; (void)value;
    if (c) odc_log(c, fmi2Error, "logStatusError", "fmi2SetRealInputDerivatives: canInterpolateInputs is false");
    return fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    odc_inst *c = (odc_inst *)comp;
    (void)vr; (void)nvr; (void)order; (void)value;
    if (c) odc_log(c, fmi2Error, "logStatusError", "fmi2GetRealOutputDerivatives: maxOutputDerivativeOrder is 0");
    return fmi2Error;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component comp, const fmi2ValueReference vUnknown[], size_t nUnknown,
                                        const fmi2ValueReference vKnown[], size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[])
{
    odc_inst *c = (odc_inst *)comp;
    (void)vUnknown; (void)nUnknown; (void)vKnown; (void)nKnown; (void)dvKnown; (void)dvUnknown;
    if (c) odc_log(c, fmi2Error, "logStatusError", "fmi2GetDirectionalDerivative: not provided");
    return fmi2Error;
}

/* ---------------------------------------------------------------------------------------- */
/* FMU state: the whole dynamic part of the instance, plain data                                */
/* ---------------------------------------------------------------------------------------- */
fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *state)
{
    odc_inst *c = (odc_inst *)comp;
    odc_saved *saved;
    if (!c || !state) return fmi2Error;
    saved = (odc_saved *)*state;
    if (!saved) {
        saved = (odc_saved *)odc_alloc(c, sizeof *saved);
        if (!saved) {
            odc_log(c, fmi2Error, "logStatusError", "fmi2GetFMUstate: out of memory");
            return fmi2Error;
        }
    }
    saved->magic = STATE_MAGIC;
    saved->size = (unsigned)sizeof *saved;
    snprintf(saved->guid, sizeof saved->guid, "%s", ODC_GUID);
    saved->d = c->d;
    *state = saved;
    return fmi2OK;
}

/* Every field that indexes or is read as a string is checked, so a damaged state (a file edited or truncated by
 * hand) is refused here instead of crashing a later fmi2DoStep. */
static int saved_fields_ok(const odc_saved *saved)
{
    const odc_dyn *d = &saved->d;
    int i;
    if (saved->magic != STATE_MAGIC || saved->size != sizeof *saved || !memchr(saved->guid, '\0', sizeof saved->guid) ||
        strcmp(saved->guid, ODC_GUID) != 0)
        return 0;
    if (d->cur < 0 || d->cur > 1 || d->phase < PH_INSTANTIATED || d->phase > PH_TERMINATED)
        return 0;
    if (d->config < -1 || d->config >= ODC_N_CONFIGS || (d->config < 0 && d->phase == PH_STEPPING))
        return 0;
    for (i = 0; i < ODC_N_STR; i++)
        if (!memchr(d->str[i], '\0', ODC_STRLEN)) return 0;
    return 1;
}

static int state_ok(odc_inst *c, const odc_saved *saved, const char *fn)
{
    if (!saved || !saved_fields_ok(saved)) {
        odc_log(c, fmi2Error, "logStatusError", "%s: not a state of this FMU", fn);
        return 0;
    }
    return 1;
}

fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate state)
{
    odc_inst *c = (odc_inst *)comp;
    if (!c || !state_ok(c, (const odc_saved *)state, "fmi2SetFMUstate")) return fmi2Error;
    c->d = ((const odc_saved *)state)->d;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *state)
{
    odc_inst *c = (odc_inst *)comp;
    if (!c || !state) return fmi2Error;
    odc_free(c, *state);
    *state = NULL;
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component comp, fmi2FMUstate state, size_t *size)
{
    (void)comp; (void)state;
    if (!size) return fmi2Error;
    *size = sizeof(odc_saved);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate state, fmi2Byte bytes[], size_t size)
{
    odc_inst *c = (odc_inst *)comp;
    if (!c || !state_ok(c, (const odc_saved *)state, "fmi2SerializeFMUstate")) return fmi2Error;
    if (size < sizeof(odc_saved)) {
        odc_log(c, fmi2Error, "logStatusError", "fmi2SerializeFMUstate: buffer of %u bytes, need %u", (unsigned)size,
                (unsigned)sizeof(odc_saved));
        return fmi2Error;
    }
    memcpy(bytes, state, sizeof(odc_saved));
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte bytes[], size_t size, fmi2FMUstate *state)
{
    odc_inst *c = (odc_inst *)comp;
    odc_saved *saved;
    if (!c || !state) return fmi2Error;
    if (size != sizeof(odc_saved)) {
        odc_log(c, fmi2Error, "logStatusError", "fmi2DeSerializeFMUstate: %u bytes are not a state of this FMU",
                (unsigned)size);
        return fmi2Error;
    }
    saved = (odc_saved *)odc_alloc(c, sizeof *saved);
    if (!saved) return fmi2Error;
    memcpy(saved, bytes, sizeof *saved);
    if (!state_ok(c, saved, "fmi2DeSerializeFMUstate")) {
        odc_free(c, saved);
        return fmi2Error;
    }
    *state = saved;
    return fmi2OK;
}
