/*
 * wcs.c — sky positions through WCSLIB (catalog.h, "WCS" section).
 *
 * All WCS work is WCSLIB's: wcspih() reads the header cards (WCSHDR_all, so
 * that SIP's A_p_q..., TPV's PVi_m and TNX's WATi_nnn are translated into
 * WCSLIB distortions), wcsfix() repairs common non-standard forms, wcssub()
 * keeps the celestial axes and makes the per-thread copies, wcsset() sets
 * each copy up once, and wcsp2s()/wcss2p() transform.  Verified against the
 * FITS WCS registry samples (tests/unit/test_wcs.c): TAN-SIP, TPV and TNX
 * agree with GalSim's independent reference points to < 0.1 mas.
 *
 * Thread safety (see catalog.h): wcsp2s()/wcss2p() write scratch memory
 * inside the wcsprm (linprm::tmpcrd when a distortion is present,
 * disprm::tmpmem) and wcsprm::err on failure, so one wcsprm cannot be shared
 * between threads.  An mp_wcs therefore holds nslot deep copies, each with
 * its own mutex.
 */
#include <stdarg.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifdef _OPENMP
#include <omp.h>
#endif

#include <wcslib/sph.h>
#include <wcslib/wcs.h>
#include <wcslib/wcsfix.h>
#include <wcslib/wcshdr.h>
#include <wcslib/wcsmath.h>

#include "catalog/catalog.h"

/* Sky frames, for mp_wcs_frame() and the J2000 conversion. */
enum {
    FR_ICRS, FR_FK5, FR_FK4, FR_FK4NOE, FR_GAPPT, FR_OTHER_EQ,
    FR_GAL, FR_ECL, FR_SGAL, FR_HECL, FR_OTHER
};

typedef struct {
    pthread_mutex_t lock;
    struct wcsprm wcs;        /* 2 celestial axes, wcsset() done */
    int have_lock, have_wcs;  /* what mp_wcs_close must undo */
} wcs_slot;

struct mp_wcs {
    int nslot;
    wcs_slot *slot;
    int lng, lat;             /* world-coordinate index of longitude, latitude */
    int frame;
    char frame_name[16];
    double equinox;           /* NaN when absent */
    int j2000;                /* 0 as is, 1 Galactic -> ICRS, -1 cannot */
};

/* The Galactic pole and the Galactic longitude of the ICRS north pole, in
 * ICRS (Hipparcos catalogue, ESA SP-1200 vol. 1 sec. 1.5.3), as WCSLIB's
 * Euler angles for sphx2s(): Galactic (l, b) "native" -> ICRS (ra, dec). */
#define GAL_POLE_RA   192.85948
#define GAL_POLE_DEC   27.12825
#define GAL_NCP_L     122.93192

/* ---- messages ----------------------------------------------------------- */

static void say(char *err, const char *fmt, ...)
    __attribute__((format(printf, 2, 3)));

static void say(char *err, const char *fmt, ...)
{
    if (!err)
        return;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(err, MP_ERRLEN, fmt, ap);
    va_end(ap);
}

/* WCSLIB's wcs_errmsg[] in matphot's words (wcsset, wcssub, wcsp2s,
 * wcss2p statuses). */
static const char *wcs_words(int status)
{
    switch (status) {
    case WCSERR_NULL_POINTER:    return "internal error (null WCS pointer)";
    case WCSERR_MEMORY:          return "out of memory";
    case WCSERR_SINGULAR_MTX:    return "the CD (or PC/CDELT) matrix is singular";
    case WCSERR_BAD_CTYPE:       return "the CTYPE cards are inconsistent or name an unknown projection";
    case WCSERR_BAD_PARAM:       return "a WCS parameter value is invalid (CDELT, PV, distortion or projection parameters)";
    case WCSERR_BAD_COORD_TRANS: return "a coordinate transformation parameter is not recognised";
    case WCSERR_ILL_COORD_TRANS: return "the celestial transformation is ill-conditioned (CRVAL/LONPOLE/LATPOLE)";
    case WCSERR_BAD_PIX:         return "the pixel position has no valid sky position (outside the projection's domain, or the distortion failed)";
    case WCSERR_BAD_WORLD:       return "the sky position has no valid pixel position (outside the projection's domain, or the distortion could not be inverted)";
    case WCSERR_BAD_WORLD_COORD: return "invalid sky coordinate";
    case WCSERR_NO_SOLUTION:     return "no solution found";
    case WCSERR_BAD_SUBIMAGE:    return "the celestial axes cannot be taken from the image's first two axes";
    case WCSERR_NON_SEPARABLE:   return "the celestial axes are coupled to the other axes (non-separable)";
    case WCSERR_UNSET:           return "internal error (WCS struct not set up)";
    default:                     break;
    }
    return "WCSLIB failed (unknown status)";
}

static const char *wcshdr_words(int status)
{
    switch (status) {
    case WCSHDRERR_NULL_POINTER: return "internal error (null pointer)";
    case WCSHDRERR_MEMORY:       return "out of memory";
    case WCSHDRERR_PARSER:       return "WCSLIB's header parser failed";
    default:                     break;
    }
    return "WCSLIB's header parser failed (unknown status)";
}

/* ---- frames ------------------------------------------------------------- */

static void trim_copy(char *dst, size_t len, const char *src)
{
    size_t n = strlen(src);
    while (n > 0 && src[n - 1] == ' ')
        n--;
    while (n > 0 && *src == ' ') {
        src++;
        n--;
    }
    if (n >= len)
        n = len - 1;
    memcpy(dst, src, n);
    dst[n] = '\0';
}

/* The frame of a set-up wcsprm, by the FITS rules for a missing RADESYS
 * (WCS Paper II sec. 3.1): ICRS without EQUINOX, FK4 before 1984, FK5
 * after. */
static void classify_frame(const struct wcsprm *c, mp_wcs *w)
{
    char sys[72], typ[8];
    trim_copy(sys, sizeof sys, c->radesys);
    trim_copy(typ, sizeof typ, c->lngtyp);
    w->equinox = undefined(c->equinox) ? NAN : c->equinox;

    if (strcmp(typ, "RA") == 0) {
        if (!sys[0]) {
            if (isnan(w->equinox))
                strcpy(sys, "ICRS");
            else
                strcpy(sys, w->equinox < 1984.0 ? "FK4" : "FK5");
        }
        if (strcmp(sys, "ICRS") == 0)
            w->frame = FR_ICRS;
        else if (strcmp(sys, "FK5") == 0)
            w->frame = FR_FK5;
        else if (strcmp(sys, "FK4") == 0)
            w->frame = FR_FK4;
        else if (strcmp(sys, "FK4-NO-E") == 0)
            w->frame = FR_FK4NOE;
        else if (strcmp(sys, "GAPPT") == 0)
            w->frame = FR_GAPPT;
        else
            w->frame = FR_OTHER_EQ;
    } else if (strcmp(typ, "GLON") == 0) {
        w->frame = FR_GAL;
    } else if (strcmp(typ, "ELON") == 0) {
        w->frame = FR_ECL;
    } else if (strcmp(typ, "SLON") == 0) {
        w->frame = FR_SGAL;
    } else if (strcmp(typ, "HLON") == 0) {
        w->frame = FR_HECL;
    } else {
        w->frame = FR_OTHER;
    }

    static const char *const names[] = {
        "icrs", "fk5", "fk4", "fk4-no-e", "gappt", NULL,
        "galactic", "ecliptic", "supergalactic", "helioecliptic", NULL
    };
    const char *nm = names[w->frame];
    if (nm)
        snprintf(w->frame_name, sizeof w->frame_name, "%s", nm);
    else if (w->frame == FR_OTHER_EQ)
        snprintf(w->frame_name, sizeof w->frame_name, "%.15s", sys);
    else
        snprintf(w->frame_name, sizeof w->frame_name, "%.7s", typ);

    /* J2000 equatorial as is: ICRS, and FK5 at equinox 2000 (or none). */
    if (w->frame == FR_ICRS
        || (w->frame == FR_FK5 && (isnan(w->equinox) || w->equinox == 2000.0)))
        w->j2000 = 0;
    else if (w->frame == FR_GAL)
        w->j2000 = 1;
    else
        w->j2000 = -1;
}

/* ---- open / close ------------------------------------------------------- */

void mp_wcs_close(mp_wcs *w)
{
    if (!w)
        return;
    for (int i = 0; i < w->nslot; i++) {
        if (w->slot[i].have_wcs)
            wcsfree(&w->slot[i].wcs);
        if (w->slot[i].have_lock)
            pthread_mutex_destroy(&w->slot[i].lock);
    }
    free(w->slot);
    free(w);
}

static int slot_count(void)
{
    int n = 1;
#ifdef _OPENMP
    n = omp_get_max_threads();
    if (omp_get_num_procs() > n)
        n = omp_get_num_procs();
#endif
    if (n < 1)
        n = 1;
    if (n > 256)
        n = 256;
    return n;
}

/* Index of the WCS to use among wcspih's: the primary (alt ' '), else the
 * first one. */
static int pick_wcs(const struct wcsprm *all, int nwcs)
{
    for (int i = 0; i < nwcs; i++)
        if (all[i].alt[0] == ' ' || all[i].alt[0] == '\0')
            return i;
    return 0;
}

/* A description of the CTYPEs for "no celestial axes" messages. */
static void ctype_list(const struct wcsprm *c, char *buf, size_t len)
{
    size_t used = 0;
    buf[0] = '\0';
    for (int i = 0; i < c->naxis && i < 4 && used < len; i++) {
        char t[72];
        trim_copy(t, sizeof t, c->ctype[i]);
        int k = snprintf(buf + used, len - used, "%sCTYPE%d='%s'",
                         i ? ", " : "", i + 1, t);
        if (k < 0)
            break;
        used += (size_t)k;
    }
}

/* The header's WCSes, as wcspih() reads them from a writable,
 * NUL-terminated copy of the cards.  On success *all holds *nwcs >= 1. */
static int header_wcs_read(const mp_image *im, int *nwcs, struct wcsprm **all,
                           char *err)
{
    if (!im->hdr || im->nkeys <= 0) {
        say(err, "no WCS: the image has no header cards");
        return MP_WCS_FAIL;
    }
    size_t n = (size_t)im->nkeys * 80;
    char *hdr = malloc(n + 1);
    if (!hdr) {
        say(err, "WCS: out of memory copying the header");
        return MP_WCS_FAIL;
    }
    memcpy(hdr, im->hdr, n);
    hdr[n] = '\0';
    int nreject = 0;
    int st = wcspih(hdr, im->nkeys, WCSHDR_all, 0, &nreject, nwcs, all);
    free(hdr);
    if (st) {
        say(err, "WCS: reading the header: %s", wcshdr_words(st));
        return MP_WCS_FAIL;
    }
    if (*nwcs <= 0 || !*all) {
        wcsvfree(nwcs, all);
        say(err, "no WCS in the header (no CTYPEn, CRPIXn, CRVALn or CDi_j cards)");
        return MP_WCS_FAIL;
    }
    return 0;
}

/* 0 when the WCS has two typed axes or more.  wcspih gives a default,
 * untyped linear WCS for a header without any WCS cards: no CTYPE at all
 * means no WCS. */
static int wcs_typed_check(const struct wcsprm *src, const char *ctypes, char *err)
{
    if (src->naxis < 2) {
        say(err, "no celestial WCS: the header's WCS has only one axis (%s)", ctypes);
        return MP_WCS_FAIL;
    }
    for (int i = 0; i < src->naxis; i++)
        if (strspn(src->ctype[i], " ") != strlen(src->ctype[i]))
            return 0;
    say(err, "no WCS in the header (no CTYPEn cards; a celestial WCS needs "
        "e.g. CTYPE1 = 'RA---TAN', CTYPE2 = 'DEC--TAN')");
    return MP_WCS_FAIL;
}

/* wcsfix's repairs, one by one: CD rows of zeros, unit spellings, the
 * NCP/GLS projections, malformed cylindrical headers; then wcsset(), and
 * the celestial axes must be the image's two.  The fixes' statuses are
 * informational (wcsset() is the judge), except for memory.  celfix and
 * cylfix call wcsset() themselves, and WCSLIB 7.12's linset() leaks its
 * matrices when called again after failing, so they are only used where
 * needed: celfix for NCP/GLS, cylfix once the WCS sets up.  When a WCS of
 * more than two axes cannot be set up, its first two are tried alone
 * later (a broken third axis does not matter to a 2-D image). */
static int wcs_repair(struct wcsprm *src, const mp_image *im, const char *ctypes,
                      char *err)
{
    int fx = cdfix(src);
    if (fx != FIXERR_MEMORY)
        fx = unitfix(7, src);
    if (fx != FIXERR_MEMORY && (strstr(ctypes, "-NCP") || strstr(ctypes, "-GLS")))
        fx = celfix(src);
    if (fx == FIXERR_MEMORY) {
        say(err, "WCS: out of memory");
        return MP_WCS_FAIL;
    }
    int st = wcsset(src);
    if (st == 0 && src->naxis == 2 && im->nx > 0 && im->ny > 0
        && im->nx <= 0x7fffffffL && im->ny <= 0x7fffffffL) {
        int naxis_len[2] = { (int)im->nx, (int)im->ny };
        if (cylfix(naxis_len, src) == FIXERR_SUCCESS)
            st = wcsset(src);
    }
    if (st == 0) {
        if (src->lng < 0 || src->lat < 0) {
            say(err, "no celestial WCS in the header (%s)", ctypes);
            return MP_WCS_FAIL;
        }
        if (src->lng + src->lat != 1) {
            int a1 = src->lng < src->lat ? src->lng : src->lat;
            int a2 = src->lng + src->lat - a1;
            say(err, "no celestial WCS on the image's two axes: the celestial "
                "axes are axes %d and %d (%s)", a1 + 1, a2 + 1, ctypes);
            return MP_WCS_FAIL;
        }
    } else if (src->naxis == 2 || st == WCSERR_MEMORY) {
        say(err, "unusable WCS in the header: %s (%s)", wcs_words(st), ctypes);
        return MP_WCS_FAIL;
    }
    return 0;
}

/* An mp_wcs with its slots allocated and none set up. */
static mp_wcs *wcs_alloc(char *err)
{
    mp_wcs *w = calloc(1, sizeof *w);
    if (w) {
        w->nslot = slot_count();
        w->slot = calloc((size_t)w->nslot, sizeof *w->slot);
        if (!w->slot) {
            free(w);
            w = NULL;
        }
    }
    if (!w)
        say(err, "WCS: out of memory");
    return w;
}

/* Slot 0: the image's first two axes of src (all of them for a 2-D WCS),
 * set up and checked to be celestial and invertible. */
static int first_slot_make(mp_wcs *w, const struct wcsprm *src, const char *ctypes,
                           char *err)
{
    wcs_slot *s0 = &w->slot[0];
    s0->wcs.flag = -1;
    int nsub = 2, axes[2] = { 1, 2 };
    int st = src->naxis == 2 ? wcssub(1, src, NULL, NULL, &s0->wcs)
                             : wcssub(1, src, &nsub, axes, &s0->wcs);
    s0->have_wcs = 1;
    if (st) {
        say(err, "WCS: %s", wcs_words(st));
        return MP_WCS_FAIL;
    }
    st = wcsset(&s0->wcs);
    if (st) {
        say(err, "unusable WCS in the header: %s (%s)", wcs_words(st), ctypes);
        return MP_WCS_FAIL;
    }
    if (s0->wcs.lng < 0 || s0->wcs.lat < 0 || s0->wcs.naxis != 2) {
        say(err, "no celestial WCS on the image's first two axes (%s)", ctypes);
        return MP_WCS_FAIL;
    }
    /* WCSLIB's matrix inversion only notices a row of zeros: test the
     * determinant of the 2x2 linear part (CD, or PC with CDELT) too. */
    const double *pc = s0->wcs.lin.pc, *cdl = s0->wcs.lin.cdelt;
    double det = (pc[0] * pc[3] - pc[1] * pc[2]) * cdl[0] * cdl[1];
    double mag = (fabs(pc[0] * pc[3]) + fabs(pc[1] * pc[2])) * fabs(cdl[0] * cdl[1]);
    if (!isfinite(det) || fabs(det) <= 1e-12 * mag) {
        say(err, "unusable WCS in the header: %s (%s)",
            wcs_words(WCSERR_SINGULAR_MTX), ctypes);
        return MP_WCS_FAIL;
    }
    w->lng = s0->wcs.lng;
    w->lat = s0->wcs.lat;
    classify_frame(&s0->wcs, w);
    return 0;
}

/* The other slots: deep copies of slot 0 (distortions included), set up
 * now so that the transformations never call wcsset(); then every lock. */
static int other_slots_make(mp_wcs *w, char *err)
{
    for (int i = 1; i < w->nslot; i++) {
        wcs_slot *s = &w->slot[i];
        s->wcs.flag = -1;
        int st = wcssub(1, &w->slot[0].wcs, NULL, NULL, &s->wcs);
        s->have_wcs = 1;
        if (!st)
            st = wcsset(&s->wcs);
        if (st) {
            say(err, "WCS: copying the WCS: %s", wcs_words(st));
            return MP_WCS_FAIL;
        }
    }
    for (int i = 0; i < w->nslot; i++) {
        if (pthread_mutex_init(&w->slot[i].lock, NULL) != 0) {
            say(err, "WCS: cannot create a lock");
            return MP_WCS_FAIL;
        }
        w->slot[i].have_lock = 1;
    }
    return 0;
}

int mp_wcs_open(const mp_image *im, mp_wcs **wp, char *err)
{
    if (wp)
        *wp = NULL;
    if (!im || !wp) {
        say(err, "WCS: internal error (null image or result pointer)");
        return MP_WCS_FAIL;
    }
    int nwcs = 0;
    struct wcsprm *all = NULL;
    if (header_wcs_read(im, &nwcs, &all, err))
        return MP_WCS_FAIL;
    struct wcsprm *src = &all[pick_wcs(all, nwcs)];
    char ctypes[256];
    ctype_list(src, ctypes, sizeof ctypes);
    mp_wcs *w = NULL;
    int st = wcs_typed_check(src, ctypes, err);
    if (!st)
        st = wcs_repair(src, im, ctypes, err);
    if (!st && !(w = wcs_alloc(err)))
        st = MP_WCS_FAIL;
    if (!st)
        st = first_slot_make(w, src, ctypes, err);
    wcsvfree(&nwcs, &all);
    if (!st)
        st = other_slots_make(w, err);
    if (st) {
        mp_wcs_close(w);
        return MP_WCS_FAIL;
    }
    *wp = w;
    return 0;
}

const char *mp_wcs_frame(const mp_wcs *w)
{
    return w ? w->frame_name : "";
}

double mp_wcs_equinox(const mp_wcs *w)
{
    return w ? w->equinox : NAN;
}

/* ---- transformations ---------------------------------------------------- */

/* A longitude in [0, 360). */
static double lng360(double a)
{
    a = fmod(a, 360.0);
    if (a < 0.0)
        a += 360.0;
    return a >= 360.0 ? 0.0 : a;
}

/* A free copy: the calling OpenMP thread's own first, then any free one;
 * wait for one only when all are busy.  NULL when locking fails. */
static wcs_slot *slot_take(const mp_wcs *w)
{
    int n = w->nslot, start = 0;
#ifdef _OPENMP
    start = omp_get_thread_num() % n;
#endif
    for (int k = 0; k < n; k++) {
        wcs_slot *s = &w->slot[(start + k) % n];
        if (pthread_mutex_trylock(&s->lock) == 0)
            return s;
    }
    wcs_slot *s = &w->slot[start];
    return pthread_mutex_lock(&s->lock) == 0 ? s : NULL;
}

static void slot_give(wcs_slot *s)
{
    pthread_mutex_unlock(&s->lock);
}

int mp_wcs_pix2sky(const mp_wcs *w, double x, double y, double *ra, double *dec, char *err)
{
    *ra = *dec = NAN;
    if (!w) {
        say(err, "WCS: internal error (no WCS)");
        return MP_WCS_FAIL;
    }
    if (!isfinite(x) || !isfinite(y)) {
        say(err, "WCS: the pixel position is not a finite number");
        return MP_WCS_BADCOORD;
    }
    double pix[2] = { x, y }, img[2], phi, theta, world[2];
    int stat = 0;
    wcs_slot *s = slot_take(w);
    if (!s) {
        say(err, "WCS: cannot take a lock");
        return MP_WCS_FAIL;
    }
    int st = wcsp2s(&s->wcs, 1, 2, pix, img, &phi, &theta, world, &stat);
    slot_give(s);
    if (st == WCSERR_BAD_PIX || (st == 0 && stat)
        || (st == 0 && (!isfinite(world[w->lng]) || !isfinite(world[w->lat])))) {
        say(err, "WCS: pixel (%.6g, %.6g) has no valid sky position (outside "
            "the projection's domain, or the distortion failed)", x, y);
        return MP_WCS_BADCOORD;
    }
    if (st) {
        say(err, "WCS: pixel to sky: %s", wcs_words(st));
        return MP_WCS_FAIL;
    }
    *ra = lng360(world[w->lng]);
    *dec = world[w->lat];
    return 0;
}

int mp_wcs_sky2pix(const mp_wcs *w, double ra, double dec, double *x, double *y, char *err)
{
    *x = *y = NAN;
    if (!w) {
        say(err, "WCS: internal error (no WCS)");
        return MP_WCS_FAIL;
    }
    if (!isfinite(ra) || !isfinite(dec) || fabs(dec) > 90.0) {
        say(err, "WCS: the sky position is not a valid (longitude, latitude)");
        return MP_WCS_BADCOORD;
    }
    double world[2], img[2], phi, theta, pix[2];
    world[w->lng] = ra;
    world[w->lat] = dec;
    int stat = 0;
    wcs_slot *s = slot_take(w);
    if (!s) {
        say(err, "WCS: cannot take a lock");
        return MP_WCS_FAIL;
    }
    int st = wcss2p(&s->wcs, 1, 2, world, &phi, &theta, img, pix, &stat);
    slot_give(s);
    if (st == WCSERR_BAD_WORLD || (st == 0 && stat)
        || (st == 0 && (!isfinite(pix[0]) || !isfinite(pix[1])))) {
        say(err, "WCS: sky position (%.9g, %.9g) has no valid pixel position "
            "(outside the projection's domain, or the distortion could not be "
            "inverted)", ra, dec);
        return MP_WCS_BADCOORD;
    }
    if (st) {
        say(err, "WCS: sky to pixel: %s", wcs_words(st));
        return MP_WCS_FAIL;
    }
    *x = pix[0];
    *y = pix[1];
    return 0;
}

/* Galactic (l, b) -> ICRS (ra, dec), degrees. */
static void gal2icrs(double l, double b, double *ra, double *dec)
{
    const double eul[5] = {
        GAL_POLE_RA, 90.0 - GAL_POLE_DEC, GAL_NCP_L,
        cos((90.0 - GAL_POLE_DEC) * D2R), sin((90.0 - GAL_POLE_DEC) * D2R)
    };
    sphx2s(eul, 1, 1, 1, 1, &l, &b, ra, dec);
    *ra = lng360(*ra);
}

static int check_j2000(const mp_wcs *w, char *err)
{
    if (w->j2000 >= 0)
        return 0;
    char eq[32] = "";
    if (!isnan(w->equinox))
        snprintf(eq, sizeof eq, ", equinox %.6g", w->equinox);
    say(err, "WCS: the header's sky frame (%s%s) cannot be converted to "
        "J2000 equatorial coordinates (only ICRS, FK5 J2000 and Galactic can)",
        w->frame_name, eq);
    return MP_WCS_FAIL;
}

int mp_wcs_pix2j2000(const mp_wcs *w, double x, double y, double *ra, double *dec, char *err)
{
    *ra = *dec = NAN;
    if (!w) {
        say(err, "WCS: internal error (no WCS)");
        return MP_WCS_FAIL;
    }
    if (check_j2000(w, err))
        return MP_WCS_FAIL;
    double a, d;
    int st = mp_wcs_pix2sky(w, x, y, &a, &d, err);
    if (st)
        return st;
    if (w->j2000 == 1)
        gal2icrs(a, d, &a, &d);
    *ra = a;
    *dec = d;
    return 0;
}

/* ---- the catalog columns ------------------------------------------------ */

/* The position pairs mp_table_add_sky converts: [0] fitted, [1] detection. */
static const char *const sky_in[2][2] = {
    { "XPSF_IMAGE", "YPSF_IMAGE" }, { "X_IMAGE", "Y_IMAGE" }
};
static const char *const sky_out[2][2] = {
    { "ALPHAPSF_J2000", "DELTAPSF_J2000" }, { "ALPHA_J2000", "DELTA_J2000" }
};

/* sky[r*4 + p*2 + {0,1}]: (RA, Dec) J2000 of row r's pair p (NaN where the
 * pair is absent or its pixel position NaN). */
static int sky_positions(const mp_table *t, const mp_wcs *w, const int cx[2],
                         const int cy[2], double *sky, char *err)
{
    int fail = 0;
    char ferr[MP_ERRLEN] = "";
    long nr = (long)t->nrow;
#pragma omp parallel for schedule(static) if (nr > 256)
    for (long r = 0; r < nr; r++) {
        for (int p = 0; p < 2; p++) {
            double *o = sky + (size_t)r * 4 + (size_t)p * 2;
            o[0] = o[1] = NAN;
            if (cx[p] < 0)
                continue;
            double x = mp_table_get(t, (size_t)r, cx[p]);
            double y = mp_table_get(t, (size_t)r, cy[p]);
            if (isnan(x) || isnan(y))
                continue;
            char e[MP_ERRLEN];
            int s = mp_wcs_pix2j2000(w, x, y, &o[0], &o[1], e);
            if (s == MP_WCS_FAIL) {
#pragma omp critical(mp_wcs_add_sky_err)
                {
                    if (!fail) {
                        fail = 1;
                        snprintf(ferr, sizeof ferr, "%s", e);
                    }
                }
            }
        }
    }
    if (fail && err)
        snprintf(err, MP_ERRLEN, "%s", ferr);
    return fail ? MP_WCS_FAIL : 0;
}

/* The sky columns of the pairs present, filled from sky[]. */
static int sky_columns_add(mp_table *t, const int cx[2], const double *sky,
                           char *err)
{
    for (int p = 0; p < 2; p++) {
        if (cx[p] < 0)
            continue;
        int ca = mp_table_add_col(t, sky_out[p][0]);
        int cd = ca < 0 ? -1 : mp_table_add_col(t, sky_out[p][1]);
        if (ca < 0 || cd < 0) {
            say(err, "sky positions: out of memory adding column %s",
                sky_out[p][ca < 0 ? 0 : 1]);
            return MP_WCS_FAIL;
        }
        for (size_t r = 0; r < t->nrow; r++) {
            mp_table_set(t, r, ca, sky[r * 4 + (size_t)p * 2]);
            mp_table_set(t, r, cd, sky[r * 4 + (size_t)p * 2 + 1]);
        }
    }
    return 0;
}

int mp_table_add_sky(mp_table *t, const mp_image *im, char *err)
{
    if (!t || !im) {
        say(err, "WCS: internal error (null table or image)");
        return MP_WCS_FAIL;
    }
    int cx[2], cy[2], npair = 0;
    for (int p = 0; p < 2; p++) {
        cx[p] = mp_table_col(t, sky_in[p][0]);
        cy[p] = mp_table_col(t, sky_in[p][1]);
        if (cx[p] < 0 || cy[p] < 0)
            cx[p] = cy[p] = -1;
        else
            npair++;
    }
    if (npair == 0) {
        say(err, "sky positions: the table has neither XPSF_IMAGE/YPSF_IMAGE "
            "nor X_IMAGE/Y_IMAGE");
        return MP_WCS_FAIL;
    }
    mp_wcs *w = NULL;
    int st = mp_wcs_open(im, &w, err);
    if (st)
        return st;
    if (check_j2000(w, err)) {
        mp_wcs_close(w);
        return MP_WCS_FAIL;
    }
    /* Compute first, then add the columns, so that a failure leaves the
     * table as it was. */
    size_t nrow = t->nrow;
    double *sky = NULL;
    if (nrow > 0 && (nrow > ((size_t)-1) / (4 * sizeof *sky)
                     || !(sky = malloc(nrow * 4 * sizeof *sky)))) {
        mp_wcs_close(w);
        say(err, "sky positions: out of memory");
        return MP_WCS_FAIL;
    }
    st = sky_positions(t, w, cx, cy, sky, err);
    mp_wcs_close(w);
    if (!st)
        st = sky_columns_add(t, cx, sky, err);
    free(sky);
    return st;
}
