/*
 * ldac.c — the card block of a FITS_LDAC catalogue's LDAC_IMHEAD table
 * (catalog.h).  SExtractor stores there the analysed image's whole header,
 * with its own SEX* keywords added, up to and including END; SCAMP takes
 * the image size and WCS from it and PSFEx its SEXBKDEV and SEXGAIN.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <fitsio.h>

#include "catalog/catalog.h"

#define CARD 80

/* Does card c hold keyword key (blank-padded to 8)? */
static int card_is(const char *c, const char *key)
{
    size_t n = strlen(key);
    if (n > 8 || memcmp(c, key, n) != 0)
        return 0;
    for (size_t i = n; i < 8; i++)
        if (c[i] != ' ')
            return 0;
    return 1;
}

/* Copy a NUL-terminated card into an 80-char slot, blank padded. */
static void put_card(char *slot, const char *card)
{
    size_t n = strlen(card);
    if (n > CARD)
        n = CARD;
    memset(slot, ' ', CARD);
    memcpy(slot, card, n);
}

/* The FITS value text of k: a quoted string ('' for a quote inside), an
 * integer, or the shortest decimal that reads back to the same double.
 * 0 when k has no FITS form (a non-finite number). */
static int value_text(const mp_card *k, char *buf, size_t len)
{
    if (k->str) {
        size_t o = 0, n = strlen(k->str);
        if (n > 68)            /* one card, no CONTINUE */
            n = 68;
        buf[o++] = '\'';
        for (size_t i = 0; i < n && o + 3 < len; i++) {
            buf[o++] = k->str[i];
            if (k->str[i] == '\'')
                buf[o++] = '\'';
        }
        while (o < 9 && o + 2 < len)   /* FITS pads short strings to 8 */
            buf[o++] = ' ';
        buf[o++] = '\'';
        buf[o] = '\0';
        return 1;
    }
    double v = k->value;
    if (!isfinite(v))
        return 0;
    if (v == floor(v) && fabs(v) < 1e15) {
        snprintf(buf, len, "%.0f", v == 0 ? 0.0 : v);
        return 1;
    }
    snprintf(buf, len, "%.15G", v);
    if (strtod(buf, NULL) != v)
        snprintf(buf, len, "%.17G", v);
    /* A real needs a "." or an exponent to stay a real for readers. */
    if (!strpbrk(buf, ".E"))
        strncat(buf, ".", len - strlen(buf) - 1);
    return 1;
}

int mp_ldac_cards(const mp_ldac_head *h, char **cards, int *ncards, char *err)
{
    *cards = NULL;
    *ncards = 0;
    static const char *const minimal[] = {
        "SIMPLE  =                    T / conforms to FITS standard",
        "BITPIX  =                    8 / no image was given",
        "NAXIS   =                    0 / no image was given",
    };
    int nsrc = 0;
    if (h && h->cards && h->ncards > 0) {
        /* Up to an END card, if the caller's block has one. */
        while (nsrc < h->ncards && !card_is(h->cards + (size_t)nsrc * CARD, "END"))
            nsrc++;
    }
    int nmin = nsrc ? 0 : (int)(sizeof minimal / sizeof minimal[0]);
    int nextra = h && h->extra ? h->nextra : 0;
    if (nextra < 0 || nsrc > (int)(((size_t)1 << 30) / CARD) - nextra - nmin - 1) {
        snprintf(err, MP_ERRLEN, "LDAC_IMHEAD: too many header cards");
        return 1;
    }
    size_t cap = (size_t)nsrc + (size_t)nmin + (size_t)nextra + 1;
    char *b = malloc(cap * CARD + 1);
    if (!b) {
        snprintf(err, MP_ERRLEN, "LDAC_IMHEAD: out of memory for %zu header cards", cap);
        return 1;
    }
    int n = 0;
    if (nsrc) {
        memcpy(b, h->cards, (size_t)nsrc * CARD);
        n = nsrc;
    }
    for (int i = 0; i < nmin; i++)
        put_card(b + (size_t)n++ * CARD, minimal[i]);

    for (int i = 0; i < nextra; i++) {
        const mp_card *k = &h->extra[i];
        char val[FLEN_VALUE], card[FLEN_CARD];
        if (!k->key || !k->key[0] || strlen(k->key) > 8) {
            snprintf(err, MP_ERRLEN, "LDAC_IMHEAD: bad keyword name '%s'",
                     k->key ? k->key : "(null)");
            free(b);
            return 1;
        }
        if (!value_text(k, val, sizeof val))
            continue;   /* no FITS form: leave the card out, as io.h does */
        int status = 0;
        /* cfitsio lays the card out (value column, comment slash). */
        if (fits_make_key(k->key, val, k->comment ? k->comment : "", card, &status)) {
            fits_clear_errmsg();
            snprintf(err, MP_ERRLEN, "LDAC_IMHEAD: cannot make a card of %s = %s", k->key, val);
            free(b);
            return 1;
        }
        /* SExtractor's addkeyto_head overwrites a key already there. */
        int at = n;
        for (int j = 0; j < n; j++)
            if (card_is(b + (size_t)j * CARD, k->key)) {
                at = j;
                break;
            }
        put_card(b + (size_t)at * CARD, card);
        if (at == n)
            n++;
    }
    put_card(b + (size_t)n++ * CARD, "END");
    b[(size_t)n * CARD] = '\0';
    *cards = b;
    *ncards = n;
    return 0;
}
