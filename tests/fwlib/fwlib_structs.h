/* fwlib32.h's structs as the FOCAS library host uses them (default branch: no FS15D, no PMCMEMD, MAX_AXIS 32,
 * natural alignment as the Linux builds use), declared as fwlib32.h declares them, and their layout table.
 * A test fixture, never shipped. Included by standin.c (the stand-in library) and by layouts.c (compiled for
 * other ABIs, e.g. gcc -m32, to compare the ctypes definitions with a 32-bit layout).
 */
#ifndef FWLIB_STRUCTS_H
#define FWLIB_STRUCTS_H
#include <stddef.h>

#define MAX_AXIS 32

typedef struct odbsys {
    short addinfo; short max_axis; char cnc_type[2]; char mt_type[2]; char series[4]; char version[4];
    char axes[2];
} ODBSYS;
typedef struct odbst {
    short hdck; short tmmode; short aut; short run; short motion; short mstb; short emergency; short alarm;
    short edit;
} ODBST;
typedef struct realprm { long prm_val; long dec_val; } REALPRM;
typedef struct iodbpsd {
    short datano; short type;
    union {
        char cdata; short idata; long ldata; REALPRM rdata;
        char cdatas[MAX_AXIS]; short idatas[MAX_AXIS]; long ldatas[MAX_AXIS]; REALPRM rdatas[MAX_AXIS];
    } u;
} IODBPSD;
typedef struct odbm { short datano; short dummy; long mcr_val; short dec_val; } ODBM;
typedef struct iodbpmc {
    short type_a; short type_d; short datano_s; short datano_e;
    union { char cdata[5]; short idata[5]; long ldata[5]; float fdata[5]; double dfdata[5]; } u;
} IODBPMC;
typedef struct odbalm { short dummy[2]; short data; } ODBALM;
typedef struct odbalmmsg {
    long alm_no; short type; short axis; short dummy; short msg_len; char alm_msg[32];
} ODBALMMSG;
typedef struct odbact { short dummy[2]; long data; } ODBACT;
typedef struct iodbtimer {
    short type; short dummy;
    union {
        struct { short year; short month; short date; } date;
        struct { short hour; short minute; short second; } time;
    } data;
} IODBTIMER;
typedef struct iodbzofs { short datano; short type; long data[MAX_AXIS]; } IODBZOFS;
typedef struct odbgcd { short group; short flag; char code[8]; } ODBGCD;
typedef struct odbmdl {
    short datano; short type;
    union {
        char g_data; char g_rdata[35]; char g_1shot[4];
        struct { long aux_data; char flag1; char flag2; } aux;
        struct { long aux_data; char flag1; char flag2; } raux1[27];
        struct { long aux_data; char flag1; char flag2; } raux2[MAX_AXIS];
    } modal;
} ODBMDL;
typedef struct odbahis2 {
    unsigned short s_no; unsigned short e_no;
    struct {
        short alm_grp; short alm_no; short axis_no; short year; short month; short day; short hour;
        short minute; short second; short len_msg; char alm_msg[32];
    } alm_his[10];
} ODBAHIS2;
typedef struct odbahis3 {
    unsigned short s_no; unsigned short e_no;
    struct {
        short alm_grp; short alm_no; short axis_no; short year; short month; short day; short hour;
        short minute; short second; short len_msg; short pth_no; short dummy; char alm_msg[32];
    } alm_his[10];
} ODBAHIS3;
typedef struct odbahis4 {
    unsigned short s_no; unsigned short e_no;
    struct {
        short alm_grp; short alm_no; short axis_no; short year; short month; short day; short hour;
        short minute; short second; short len_msg; short pth_no; short dummy; char alm_msg[64];
    } alm_his[10];
} ODBAHIS4;

/* X(type, "field path", member designator) for every field; nested fields are alm_his[0]'s, u's ... */
#define ALMHIS_HEAD(X, T)                                                                                 \
    X(T, "alm_his.alm_grp", alm_his[0].alm_grp) X(T, "alm_his.alm_no", alm_his[0].alm_no)              \
    X(T, "alm_his.axis_no", alm_his[0].axis_no) X(T, "alm_his.year", alm_his[0].year)                  \
    X(T, "alm_his.month", alm_his[0].month) X(T, "alm_his.day", alm_his[0].day)                        \
    X(T, "alm_his.hour", alm_his[0].hour) X(T, "alm_his.minute", alm_his[0].minute)                    \
    X(T, "alm_his.second", alm_his[0].second) X(T, "alm_his.len_msg", alm_his[0].len_msg)
#define FWLIB_FIELDS(X) \
    X(ODBSYS, "addinfo", addinfo) \
    X(ODBSYS, "max_axis", max_axis) \
    X(ODBSYS, "cnc_type", cnc_type) \
    X(ODBSYS, "mt_type", mt_type) \
    X(ODBSYS, "series", series) \
    X(ODBSYS, "version", version) \
    X(ODBSYS, "axes", axes) \
    X(ODBST, "hdck", hdck) \
    X(ODBST, "tmmode", tmmode) \
    X(ODBST, "aut", aut) \
    X(ODBST, "run", run) \
    X(ODBST, "motion", motion) \
    X(ODBST, "mstb", mstb) \
    X(ODBST, "emergency", emergency) \
    X(ODBST, "alarm", alarm) \
    X(ODBST, "edit", edit) \
    X(REALPRM, "prm_val", prm_val) \
    X(REALPRM, "dec_val", dec_val) \
    X(IODBPSD, "datano", datano) \
    X(IODBPSD, "type", type) \
    X(IODBPSD, "u", u) \
    X(IODBPSD, "u.cdata", u.cdata) \
    X(IODBPSD, "u.idata", u.idata) \
    X(IODBPSD, "u.ldata", u.ldata) \
    X(IODBPSD, "u.rdata", u.rdata) \
    X(IODBPSD, "u.rdata.prm_val", u.rdata.prm_val) \
    X(IODBPSD, "u.rdata.dec_val", u.rdata.dec_val) \
    X(IODBPSD, "u.cdatas", u.cdatas) \
    X(IODBPSD, "u.idatas", u.idatas) \
    X(IODBPSD, "u.ldatas", u.ldatas) \
    X(IODBPSD, "u.rdatas", u.rdatas) \
    X(IODBPSD, "u.rdatas.prm_val", u.rdatas[0].prm_val) \
    X(IODBPSD, "u.rdatas.dec_val", u.rdatas[0].dec_val) \
    X(ODBM, "datano", datano) \
    X(ODBM, "dummy", dummy) \
    X(ODBM, "mcr_val", mcr_val) \
    X(ODBM, "dec_val", dec_val) \
    X(IODBPMC, "type_a", type_a) \
    X(IODBPMC, "type_d", type_d) \
    X(IODBPMC, "datano_s", datano_s) \
    X(IODBPMC, "datano_e", datano_e) \
    X(IODBPMC, "u", u) \
    X(IODBPMC, "u.cdata", u.cdata) \
    X(IODBPMC, "u.idata", u.idata) \
    X(IODBPMC, "u.ldata", u.ldata) \
    X(IODBPMC, "u.fdata", u.fdata) \
    X(IODBPMC, "u.dfdata", u.dfdata) \
    X(ODBALM, "dummy", dummy) \
    X(ODBALM, "data", data) \
    X(ODBALMMSG, "alm_no", alm_no) \
    X(ODBALMMSG, "type", type) \
    X(ODBALMMSG, "axis", axis) \
    X(ODBALMMSG, "dummy", dummy) \
    X(ODBALMMSG, "msg_len", msg_len) \
    X(ODBALMMSG, "alm_msg", alm_msg) \
    X(ODBACT, "dummy", dummy) \
    X(ODBACT, "data", data) \
    X(IODBTIMER, "type", type) \
    X(IODBTIMER, "dummy", dummy) \
    X(IODBTIMER, "data", data) \
    X(IODBTIMER, "data.date", data.date) \
    X(IODBTIMER, "data.date.year", data.date.year) \
    X(IODBTIMER, "data.date.month", data.date.month) \
    X(IODBTIMER, "data.date.date", data.date.date) \
    X(IODBTIMER, "data.time", data.time) \
    X(IODBTIMER, "data.time.hour", data.time.hour) \
    X(IODBTIMER, "data.time.minute", data.time.minute) \
    X(IODBTIMER, "data.time.second", data.time.second) \
    X(IODBZOFS, "datano", datano) \
    X(IODBZOFS, "type", type) \
    X(IODBZOFS, "data", data) \
    X(ODBGCD, "group", group) \
    X(ODBGCD, "flag", flag) \
    X(ODBGCD, "code", code) \
    X(ODBMDL, "datano", datano) \
    X(ODBMDL, "type", type) \
    X(ODBMDL, "modal", modal) \
    X(ODBMDL, "modal.g_data", modal.g_data) \
    X(ODBMDL, "modal.g_rdata", modal.g_rdata) \
    X(ODBMDL, "modal.g_1shot", modal.g_1shot) \
    X(ODBMDL, "modal.aux", modal.aux) \
    X(ODBMDL, "modal.aux.aux_data", modal.aux.aux_data) \
    X(ODBMDL, "modal.aux.flag1", modal.aux.flag1) \
    X(ODBMDL, "modal.aux.flag2", modal.aux.flag2) \
    X(ODBMDL, "modal.raux1", modal.raux1) \
    X(ODBMDL, "modal.raux1.aux_data", modal.raux1[0].aux_data) \
    X(ODBMDL, "modal.raux1.flag1", modal.raux1[0].flag1) \
    X(ODBMDL, "modal.raux1.flag2", modal.raux1[0].flag2) \
    X(ODBMDL, "modal.raux2", modal.raux2) \
    X(ODBMDL, "modal.raux2.aux_data", modal.raux2[0].aux_data) \
    X(ODBMDL, "modal.raux2.flag1", modal.raux2[0].flag1) \
    X(ODBMDL, "modal.raux2.flag2", modal.raux2[0].flag2) \
    X(ODBAHIS2, "s_no", s_no) \
    X(ODBAHIS2, "e_no", e_no) \
    X(ODBAHIS2, "alm_his", alm_his) \
    ALMHIS_HEAD(X, ODBAHIS2) \
    X(ODBAHIS2, "alm_his.alm_msg", alm_his[0].alm_msg) \
    X(ODBAHIS3, "s_no", s_no) \
    X(ODBAHIS3, "e_no", e_no) \
    X(ODBAHIS3, "alm_his", alm_his) \
    ALMHIS_HEAD(X, ODBAHIS3) \
    X(ODBAHIS3, "alm_his.pth_no", alm_his[0].pth_no) \
    X(ODBAHIS3, "alm_his.dummy", alm_his[0].dummy) \
    X(ODBAHIS3, "alm_his.alm_msg", alm_his[0].alm_msg) \
    X(ODBAHIS4, "s_no", s_no) \
    X(ODBAHIS4, "e_no", e_no) \
    X(ODBAHIS4, "alm_his", alm_his) \
    ALMHIS_HEAD(X, ODBAHIS4) \
    X(ODBAHIS4, "alm_his.pth_no", alm_his[0].pth_no) \
    X(ODBAHIS4, "alm_his.dummy", alm_his[0].dummy) \
    X(ODBAHIS4, "alm_his.alm_msg", alm_his[0].alm_msg)

/* S(type) for every struct the library calls take */
#define FWLIB_STRUCTS(S) S(ODBSYS) S(ODBST) S(REALPRM) S(IODBPSD) S(ODBM) S(IODBPMC) S(ODBALM) S(ODBALMMSG) S(ODBACT) S(IODBTIMER) S(IODBZOFS) S(ODBGCD) S(ODBMDL) S(ODBAHIS2) S(ODBAHIS3) S(ODBAHIS4)

#endif
