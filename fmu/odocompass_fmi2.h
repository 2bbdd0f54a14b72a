/* OdoCompass native FMU: the instance types shared by odocompass_fmi2.c and odocompass_fmi2_state.c.
 * Hand-written and model-independent; sizes come from the generated odocompass_model.h. */
#ifndef ODOCOMPASS_FMI2_H
#define ODOCOMPASS_FMI2_H
#include "fmi2Functions.h"
#include "odocompass_model.h"

enum { PH_INSTANTIATED, PH_INIT, PH_STEPPING, PH_TERMINATED };
#define STATE_MAGIC 0x4f444353u /* "ODCS" */
#define MSG_LEN 4096

typedef struct {
    int phase;
    int config;       /* index into ODC_CONFIGS once initialized */
    int cur;          /* which of s[0], s[1] holds the state */
    int strikes;      /* consecutive samples refused for implausible counters */
    int discarded;
    int outputs_valid;
    double t_start, t_last;
    double p[ODC_N_PARAM];
    double s[2][ODC_N_STATE];
    double x[ODC_N_IN];
    double o[ODC_N_OUT];
    int cfg_bool[ODC_N_BOOL];
    char str[ODC_N_STR][ODC_STRLEN];
    /* a wheel counter that stopped counting (watch_counters): per side, a run under way, reported, its start (s) */
    int stop_running[2], stop_reported[2];
    double stop_since[2];
} odc_dyn;

typedef struct {
    unsigned magic;
    unsigned size;
    char guid[64];
    odc_dyn d;
} odc_saved;

typedef struct {
    odc_dyn d;
    fmi2CallbackFunctions cb;
    char name[256];
    int logging_on;
    int category_on[ODC_N_CATEGORIES];
    char text[MSG_LEN];
    char msg[2 * MSG_LEN];
} odc_inst;

void *odc_alloc(const odc_inst *c, size_t n);
void odc_free(const odc_inst *c, void *ptr);
void odc_log(odc_inst *c, fmi2Status status, const char *category, const char *fmt, ...);

#endif
