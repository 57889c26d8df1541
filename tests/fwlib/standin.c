/* A stand-in for FANUC's FOCAS library, for the test suite only (never shipped, never installed).
 *
 * It exports the function names and signatures of fwlib32.h that edge.fwlib calls, declares the structs
 * exactly as fwlib32.h does (default branch, natural alignment as the Linux builds use), fills them from
 * in-memory state (parameters, macros, PMC, an alarm-history ring) and exports hooks the tests drive:
 * standin_* functions set state, inject a hang or a lost handle, and report every struct layout the C
 * compiler chose (standin_layouts), which tests/unit/fwlib/test_structs.py compares with the ctypes side.
 *
 * Build: gcc -shared -fPIC -O1 -pthread -o libfwlib-standin.so standin.c
 */
#include <pthread.h>
#include <stddef.h>
#include <stdio.h>
#include <string.h>
#include <time.h>

#include "fwlib_structs.h"

#define EW_HANDLE (-8)
#define EW_SOCKET (-16)
#define EW_OK 0
#define EW_FUNC 1
#define EW_LENGTH 2
#define EW_NUMBER 3
#define EW_ATTRIB 4
#define EW_DATA 5
#define EW_PASSWD 17

/* ---- layouts as this compiler lays them out ------------------------------------------------------ */
struct layout { const char *type; const char *field; size_t offset; size_t size; };
#define L(T, name, member) {#T, name, offsetof(T, member), sizeof(((T *)0)->member)},
static const struct layout LAYOUTS[] = { FWLIB_FIELDS(L) };
#define SIZE_OF(T) {#T, sizeof(T)},
static const struct { const char *type; size_t size; } SIZES[] = { FWLIB_STRUCTS(SIZE_OF) };
static char layout_text[16384];

/* "TYPE FIELD OFFSET SIZE" lines for every field, then "TYPE * 0 SIZEOF" per struct. */
const char *standin_layouts(void) {
    size_t at = 0;
    for (size_t i = 0; i < sizeof(LAYOUTS) / sizeof(LAYOUTS[0]); i++)
        at += snprintf(layout_text + at, sizeof(layout_text) - at, "%s %s %zu %zu\n", LAYOUTS[i].type,
                       LAYOUTS[i].field, LAYOUTS[i].offset, LAYOUTS[i].size);
    for (size_t i = 0; i < sizeof(SIZES) / sizeof(SIZES[0]); i++)
        at += snprintf(layout_text + at, sizeof(layout_text) - at, "%s * 0 %zu\n", SIZES[i].type,
                       SIZES[i].size);
    return layout_text;
}

/* ---- in-memory CNC state ------------------------------------------------------------------------- */
#define MAX_PARAMS 64
#define MAX_MACROS 64
#define PMC_BYTES 10000
#define MAX_HISTORY 250
#define MAX_HANDLES 16
#define WORK_OFFSETS 7  /* 0 external, 1..6 G54..G59 */
#define STANDIN_AXES 3  /* cnc_sysinfo says "03" */

struct param { short number; short type; long value; long dec; };  /* type 0 bit .. 4 real */
struct macro { short number; long mcr_val; short dec_val; };
struct alarm_entry {
    short year, month, day, hour, minute, second, axis_no, alm_grp, alm_no; char msg[65]; short len;
};

static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static struct param params[MAX_PARAMS];
static int n_params;
static struct macro macros[MAX_MACROS];
static int n_macros;
static unsigned char pmc[14][PMC_BYTES]; /* by fwlib adr_type G0 F1 Y2 X3 A4 R5 T6 K7 C8 D9 M10 N11 E12 Z13 */
static struct alarm_entry history[MAX_HISTORY]; /* history[0] is the newest */
static int n_history;
static int pwe = 1;
static int history_version = 4; /* the newest cnc_rdalmhistryN this "control" supports */
static int handles_valid[MAX_HANDLES];
static int refuse_connects;
static int started_up;
static int hang_macro = -1;
static int hang_history;  /* the next this many cnc_rdalmhistryN calls hang (-1: every one) */
static int fail_history;  /* then the next this many answer fail_history_code */
static short fail_history_code;
static int calls_rdalmhistry;
static volatile int released;
static int calls_rdpmcrng, calls_wrpmcrng, calls_allclibhndl3;
static short last_wrpmc_start, last_wrpmc_end;
static long work_offsets[WORK_OFFSETS][STANDIN_AXES]; /* in the least input increment */
static int calls_rdzofs;
static long tool_in_use;
#define GCODE_GROUPS 4
static const char *const gcodes[GCODE_GROUPS] = {"G01", "G17", "G90", "G54"};
static const short gcode_groups[GCODE_GROUPS] = {0, 1, 2, 13};
static short last_rdzofs_length;

void standin_reset(void) {
    pthread_mutex_lock(&lock);
    n_params = n_macros = n_history = 0;
    memset(pmc, 0, sizeof(pmc));
    pwe = 1; history_version = 4; refuse_connects = 0; hang_macro = -1; released = 0;
    hang_history = fail_history = 0; fail_history_code = 0;
    calls_rdpmcrng = calls_wrpmcrng = calls_allclibhndl3 = calls_rdzofs = calls_rdalmhistry = 0;
    memset(work_offsets, 0, sizeof(work_offsets)); last_rdzofs_length = 0; tool_in_use = 0;
    pthread_mutex_unlock(&lock);
}
void standin_set_param(short number, short type, long value, long dec) {
    pthread_mutex_lock(&lock);
    int i = 0;
    while (i < n_params && params[i].number != number) i++;
    if (i == n_params && n_params < MAX_PARAMS) n_params++;
    if (i < MAX_PARAMS) { params[i].number = number; params[i].type = type; params[i].value = value; params[i].dec = dec; }
    pthread_mutex_unlock(&lock);
}
long standin_param_value(short number) {
    for (int i = 0; i < n_params; i++) if (params[i].number == number) return params[i].value;
    return -999999;
}
void standin_set_pwe(int on) { pwe = on; }
void standin_set_history_version(int version) { history_version = version; }
void standin_refuse_connects(int count) { refuse_connects = count; }
void standin_hang_macro(int number) { hang_macro = number; released = 0; }
void standin_release(void) { released = 1; }
/* The next `calls` calls of the history function the control has hang until released (60 s at most), then
 * answer EW_SOCKET, as a call on a dead connection does; -1 hangs every call. */
void standin_hang_history(int calls) { hang_history = calls; released = 0; }
/* The next `calls` calls of the history function answer `code` (after any hangs); -1: every call. */
void standin_fail_history(short code, int calls) { fail_history_code = code; fail_history = calls; }
int standin_calls(const char *name) {
    if (!strcmp(name, "pmc_rdpmcrng")) return calls_rdpmcrng;
    if (!strcmp(name, "pmc_wrpmcrng")) return calls_wrpmcrng;
    if (!strcmp(name, "cnc_allclibhndl3")) return calls_allclibhndl3;
    if (!strcmp(name, "cnc_rdzofs")) return calls_rdzofs;
    if (!strcmp(name, "cnc_rdalmhistry")) return calls_rdalmhistry;  /* of the version the control has */
    return -1;
}
void standin_set_work_offset(short number, short axis, long value) {
    if (number >= 0 && number < WORK_OFFSETS && axis >= 1 && axis <= STANDIN_AXES) work_offsets[number][axis - 1] = value;
}
short standin_last_rdzofs_length(void) { return last_rdzofs_length; }
void standin_set_tool(long t) { tool_in_use = t; }
int standin_started_up(void) { return started_up; }
/* Every handle handed out so far now answers EW_HANDLE, as after the CNC dropped the connection. */
void standin_drop_handles(void) {
    pthread_mutex_lock(&lock);
    for (int i = 0; i < MAX_HANDLES; i++) handles_valid[i] = 0;
    pthread_mutex_unlock(&lock);
}
/* Push an alarm (the newest first); len -1 means strlen(msg), any other value is stored as given. Dates are stored as given, even bad ones. */
void standin_push_alarm(short year, short month, short day, short hour, short minute, short second,
                        short axis_no, short alm_grp, short alm_no, const char *msg, short len) {
    pthread_mutex_lock(&lock);
    if (n_history == MAX_HISTORY) n_history--;
    memmove(&history[1], &history[0], sizeof(history[0]) * n_history);
    struct alarm_entry *e = &history[0];
    e->year = year; e->month = month; e->day = day; e->hour = hour; e->minute = minute; e->second = second;
    e->axis_no = axis_no; e->alm_grp = alm_grp; e->alm_no = alm_no;
    memset(e->msg, 0, sizeof(e->msg));
    strncpy(e->msg, msg, 64);
    e->len = len == -1 ? (short)strlen(e->msg) : len;
    n_history++;
    pthread_mutex_unlock(&lock);
}
void standin_set_pmc(short adr_type, unsigned short address, unsigned char value) {
    if (adr_type >= 0 && adr_type < 14 && address < PMC_BYTES) pmc[adr_type][address] = value;
}
int standin_pmc(short adr_type, unsigned short address) { return pmc[adr_type][address]; }
short standin_last_wrpmc_start(void) { return last_wrpmc_start; }
short standin_last_wrpmc_end(void) { return last_wrpmc_end; }

static int valid(unsigned short h) { return h >= 1 && h < MAX_HANDLES && handles_valid[h]; }
#define CHECK_HANDLE(h) do { if (!valid(h)) return EW_HANDLE; } while (0)

/* ---- the FOCAS functions ------------------------------------------------------------------------- */
short cnc_startupprocess(long level, const char *filename) { (void)level; (void)filename; started_up = 1; return EW_OK; }
short cnc_exitprocess(void) { started_up = 0; return EW_OK; }

short cnc_allclibhndl3(const char *ip, unsigned short port, long timeout, unsigned short *handle) {
    (void)ip; (void)port; (void)timeout;
    pthread_mutex_lock(&lock);
    calls_allclibhndl3++;
    if (refuse_connects > 0) { refuse_connects--; pthread_mutex_unlock(&lock); return EW_SOCKET; }
    for (unsigned short h = 1; h < MAX_HANDLES; h++) {
        if (!handles_valid[h]) { handles_valid[h] = 1; *handle = h; pthread_mutex_unlock(&lock); return EW_OK; }
    }
    pthread_mutex_unlock(&lock);
    return EW_SOCKET;
}
short cnc_freelibhndl(unsigned short h) { if (h < MAX_HANDLES) handles_valid[h] = 0; return EW_OK; }

short cnc_sysinfo(unsigned short h, ODBSYS *out) {
    CHECK_HANDLE(h);
    memset(out, 0, sizeof(*out));
    out->addinfo = 2; out->max_axis = MAX_AXIS;
    memcpy(out->cnc_type, "31", 2); memcpy(out->mt_type, " M", 2); memcpy(out->series, "G421", 4);
    memcpy(out->version, "0013", 4); memcpy(out->axes, "03", 2);
    return EW_OK;
}
short cnc_statinfo(unsigned short h, ODBST *out) {
    CHECK_HANDLE(h);
    memset(out, 0, sizeof(*out));
    out->aut = 1; out->run = 3; out->motion = 1;
    return EW_OK;
}
static struct param *find_param(short number) {
    for (int i = 0; i < n_params; i++) if (params[i].number == number) return &params[i];
    return NULL;
}
static size_t param_width(short type) {
    switch (type) {
    case 0: case 1: return sizeof(char);
    case 2: return sizeof(short);
    case 3: return sizeof(long);
    default: return sizeof(REALPRM);
    }
}
static short read_psd(unsigned short h, short number, short axis, short length, IODBPSD *out) {
    CHECK_HANDLE(h);
    pthread_mutex_lock(&lock);
    struct param *p = find_param(number);
    if (!p) { pthread_mutex_unlock(&lock); return EW_NUMBER; }
    if (axis < 0) { pthread_mutex_unlock(&lock); return EW_ATTRIB; }
    if ((size_t)length < offsetof(IODBPSD, u) + param_width(p->type)) { pthread_mutex_unlock(&lock); return EW_LENGTH; }
    out->datano = number; out->type = axis;
    switch (p->type) {
    case 0: case 1: out->u.cdata = (char)p->value; break;
    case 2: out->u.idata = (short)p->value; break;
    case 3: out->u.ldata = p->value; break;
    default: out->u.rdata.prm_val = p->value; out->u.rdata.dec_val = p->dec; break;
    }
    pthread_mutex_unlock(&lock);
    return EW_OK;
}
short cnc_rdparam(unsigned short h, short number, short axis, short length, IODBPSD *out) {
    return read_psd(h, number, axis, length, out);
}
short cnc_rddiag(unsigned short h, short number, short axis, short length, IODBPSD *out) {
    return read_psd(h, number, axis, length, out);
}
short cnc_wrparam(unsigned short h, short length, IODBPSD *in) {
    CHECK_HANDLE(h);
    if (!pwe) return EW_PASSWD;
    pthread_mutex_lock(&lock);
    struct param *p = find_param(in->datano);
    short rc = EW_OK;
    if (!p) rc = EW_NUMBER;
    else if ((size_t)length != offsetof(IODBPSD, u) + param_width(p->type)) rc = EW_LENGTH;
    else switch (p->type) {
        case 0: p->value = (unsigned char)in->u.cdata; break;
        case 1: p->value = (signed char)in->u.cdata; break;
        case 2: p->value = in->u.idata; break;
        case 3: p->value = in->u.ldata; break;
        default: p->value = in->u.rdata.prm_val; p->dec = in->u.rdata.dec_val; break;
    }
    pthread_mutex_unlock(&lock);
    return rc;
}
static struct macro *find_macro(short number, int create) {
    for (int i = 0; i < n_macros; i++) if (macros[i].number == number) return &macros[i];
    if (!create || n_macros == MAX_MACROS) return NULL;
    macros[n_macros].number = number; macros[n_macros].mcr_val = 0; macros[n_macros].dec_val = -1;
    return &macros[n_macros++];
}
short cnc_rdmacro(unsigned short h, short number, short length, ODBM *out) {
    CHECK_HANDLE(h);
    if (length < (short)sizeof(ODBM)) return EW_LENGTH;
    if (number == hang_macro) {  /* a call that hangs: until released, or 60 s at most */
        for (int i = 0; i < 6000 && !released; i++) { struct timespec t = {0, 10000000}; nanosleep(&t, NULL); }
    }
    if (number < 1 || number > 9999) return EW_NUMBER;
    pthread_mutex_lock(&lock);
    struct macro *m = find_macro(number, 0);
    out->datano = number; out->dummy = 0;
    out->mcr_val = m ? m->mcr_val : 0; out->dec_val = m ? m->dec_val : -1;
    pthread_mutex_unlock(&lock);
    return EW_OK;
}
short cnc_wrmacro(unsigned short h, short number, short length, long mcr_val, short dec_val) {
    CHECK_HANDLE(h);
    if (length != 10) return EW_LENGTH;
    if (number < 1 || number > 9999) return EW_NUMBER;
    pthread_mutex_lock(&lock);
    struct macro *m = find_macro(number, 1);
    if (m) { m->mcr_val = mcr_val; m->dec_val = dec_val; }
    pthread_mutex_unlock(&lock);
    return m ? EW_OK : EW_DATA;
}
static size_t pmc_width(short data_type) {
    switch (data_type) { case 0: return 1; case 1: return 2; case 2: return 4; case 4: return 4; case 5: return 8; }
    return 0;
}
short pmc_rdpmcrng(unsigned short h, short adr_type, short data_type, unsigned short s, unsigned short e,
                   unsigned short length, IODBPMC *out) {
    CHECK_HANDLE(h);
    calls_rdpmcrng++;
    size_t width = pmc_width(data_type);
    if (adr_type < 0 || adr_type > 13 || !width) return EW_ATTRIB;
    if (e < s || e >= PMC_BYTES) return EW_NUMBER;
    size_t n = e - s + 1;
    if (n % width || length != 8 + n) return EW_LENGTH;
    out->type_a = adr_type; out->type_d = data_type; out->datano_s = s; out->datano_e = e;
    memcpy(out->u.cdata, &pmc[adr_type][s], n);
    return EW_OK;
}
short pmc_wrpmcrng(unsigned short h, unsigned short length, IODBPMC *in) {
    CHECK_HANDLE(h);
    calls_wrpmcrng++;
    unsigned short s = in->datano_s, e = in->datano_e;
    if (in->type_a < 0 || in->type_a > 13 || in->type_d != 0) return EW_ATTRIB;
    if (e < s || e >= PMC_BYTES) return EW_NUMBER;
    size_t n = e - s + 1;
    if (n > 32 || length != 8 + n) return EW_LENGTH;
    last_wrpmc_start = s; last_wrpmc_end = e;
    memcpy(&pmc[in->type_a][s], in->u.cdata, n);
    return EW_OK;
}
short cnc_rdalmhisno(unsigned short h, unsigned short *count) {
    CHECK_HANDLE(h);
    *count = (unsigned short)n_history;
    return EW_OK;
}
/* The injected trouble of one history call: 0, or the code it answers (after hanging, when told to). */
static short history_fault(void) {
    pthread_mutex_lock(&lock);
    calls_rdalmhistry++;
    int hang = hang_history != 0;
    if (hang_history > 0) hang_history--;
    short code = 0;
    if (!hang && fail_history != 0) { code = fail_history_code; if (fail_history > 0) fail_history--; }
    pthread_mutex_unlock(&lock);
    if (hang) {
        for (int i = 0; i < 6000 && !released; i++) { struct timespec t = {0, 10000000}; nanosleep(&t, NULL); }
        return EW_SOCKET;
    }
    return code;
}
/* cnc_rdalmhistryN: entries s_no..e_no (1 = newest), at most 10 per call, e_no trimmed to what exists. */
#define FILL_HISTORY(T, MSGMAX, VERSION, WITH_PATH)                                                    \
    short cnc_rdalmhistry##VERSION(unsigned short h, unsigned short s, unsigned short e,              \
                                   unsigned short length, T *out) {                                  \
        CHECK_HANDLE(h);                                                                             \
        if (history_version < VERSION) return EW_FUNC;                                               \
        short fault = history_fault();                                                               \
        if (fault) return fault;                                                                     \
        if (length != sizeof(T)) return EW_LENGTH;                                                   \
        if (s < 1 || e < s || e - s >= 10) return EW_NUMBER;                                         \
        pthread_mutex_lock(&lock);                                                                   \
        if (e > n_history) e = (unsigned short)n_history;                                            \
        memset(out, 0, sizeof(T));                                                                   \
        out->s_no = s; out->e_no = e;                                                                \
        for (int i = 0; s + i <= e; i++) {                                                           \
            struct alarm_entry *a = &history[s - 1 + i];                                             \
            out->alm_his[i].alm_grp = a->alm_grp; out->alm_his[i].alm_no = a->alm_no;                \
            out->alm_his[i].axis_no = a->axis_no; out->alm_his[i].year = a->year;                    \
            out->alm_his[i].month = a->month; out->alm_his[i].day = a->day;                          \
            out->alm_his[i].hour = a->hour; out->alm_his[i].minute = a->minute;                      \
            out->alm_his[i].second = a->second;                                                      \
            out->alm_his[i].len_msg = a->len > MSGMAX ? MSGMAX : a->len;                             \
            memcpy(out->alm_his[i].alm_msg, a->msg, MSGMAX);                                         \
            WITH_PATH                                                                                \
        }                                                                                            \
        pthread_mutex_unlock(&lock);                                                                 \
        return EW_OK;                                                                                \
    }
FILL_HISTORY(ODBAHIS2, 32, 2, )
FILL_HISTORY(ODBAHIS3, 32, 3, out->alm_his[i].pth_no = 1;)
FILL_HISTORY(ODBAHIS4, 64, 4, out->alm_his[i].pth_no = 1;)

short cnc_alarm(unsigned short h, ODBALM *out) {
    CHECK_HANDLE(h);
    memset(out, 0, sizeof(*out));
    out->data = 0;
    return EW_OK;
}
short cnc_rdalmmsg(unsigned short h, short type, short *num, ODBALMMSG *out) {
    CHECK_HANDLE(h);
    (void)type; (void)out;
    *num = 0;
    return EW_OK;
}
short cnc_actf(unsigned short h, ODBACT *out) { CHECK_HANDLE(h); memset(out, 0, sizeof(*out)); out->data = 1200; return EW_OK; }
short cnc_acts(unsigned short h, ODBACT *out) { CHECK_HANDLE(h); memset(out, 0, sizeof(*out)); out->data = 8000; return EW_OK; }
/* type -1: every axis, which needs length >= 4 + axes * sizeof(long); type n: axis n alone */
short cnc_rdzofs(unsigned short h, short number, short axis, short length, IODBZOFS *out) {
    CHECK_HANDLE(h);
    calls_rdzofs++;
    last_rdzofs_length = length;
    if (number < 0 || number >= WORK_OFFSETS) return EW_NUMBER;
    if (axis != -1 && (axis < 1 || axis > STANDIN_AXES)) return EW_ATTRIB;
    int count = axis == -1 ? STANDIN_AXES : 1;
    if (length < (short)(offsetof(IODBZOFS, data) + count * sizeof(long))) return EW_LENGTH;
    out->datano = number; out->type = axis;
    for (int i = 0; i < count; i++) out->data[i] = work_offsets[number][axis == -1 ? i : axis - 1];
    return EW_OK;
}
/* type -1 (every group), block 1 (active): *num in = room in out[], out = codes written */
short cnc_rdgcode(unsigned short h, short type, short block, short *num, ODBGCD *out) {
    CHECK_HANDLE(h);
    if (type != -1 || block != 1) return EW_ATTRIB;
    if (*num < GCODE_GROUPS) return EW_LENGTH;
    for (int i = 0; i < GCODE_GROUPS; i++) {
        memset(&out[i], 0, sizeof(out[i]));
        out[i].group = gcode_groups[i];
        strncpy(out[i].code, gcodes[i], sizeof(out[i].code));
    }
    *num = GCODE_GROUPS;
    return EW_OK;
}
/* type 108 (T code), block 0 (active) only */
short cnc_modal(unsigned short h, short type, short block, ODBMDL *out) {
    CHECK_HANDLE(h);
    if (type != 108 || block != 0) return EW_ATTRIB;
    memset(out, 0, sizeof(*out));
    out->datano = type; out->type = block;
    out->modal.aux.aux_data = tool_in_use; out->modal.aux.flag1 = 1;
    return EW_OK;
}
short cnc_gettimer(unsigned short h, IODBTIMER *io) {
    CHECK_HANDLE(h);
    time_t now = time(NULL);
    struct tm t;
    gmtime_r(&now, &t);
    if (io->type == 0) { io->data.date.year = t.tm_year + 1900; io->data.date.month = t.tm_mon + 1; io->data.date.date = t.tm_mday; }
    else if (io->type == 1) { io->data.time.hour = t.tm_hour; io->data.time.minute = t.tm_min; io->data.time.second = t.tm_sec; }
    else return EW_ATTRIB;
    return EW_OK;
}
