/*
 * export.c — a scene as files, so that another program (IRAF DAOPHOT for
 * bench/daophot_points.txt) can be run on the very same pixels:
 *
 *   DIR/SCENE.fits       the frame in electrons (GAIN 1, RDNOISE 3); the
 *                        single-star scenes as a mosaic of their 60x60
 *                        frames (tile k at column k % T, row k / T, T the
 *                        smallest square side), so every star is isolated
 *   DIR/SCENE.truth      one line per star: x y (1-based, frame or mosaic
 *                        pixels), flux [e-], mag, sigma_E and sigma_X of its
 *                        CRLB, start x y (what the sweep's fits start from)
 *   DIR/SCENE_psf.fits   the PSF table as given (OVERSAMP keyword)
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "tests/bench/sweep/sw.h"

int sw_export(const char *dir, const sw_scene *sc, char *err)
{
    char path[1024];
    long tiles = sc->kind == SW_SINGLE ? (long)ceil(sqrt((double)sc->n)) : 1;
    long nx = sc->kind == SW_SINGLE ? tiles * SW_NX : sc->fnx;
    long ny = sc->kind == SW_SINGLE ? ((sc->n + tiles - 1) / tiles) * SW_NX : sc->fny;
    float *img = sc->img;
    if (sc->kind == SW_SINGLE) {
        img = malloc((size_t)nx * (size_t)ny * sizeof *img);
        if (!img) {
            snprintf(err, MP_ERRLEN, "out of memory for the %ldx%ld mosaic", nx, ny);
            return 1;
        }
        for (size_t i = 0; i < (size_t)nx * (size_t)ny; i++)
            img[i] = SW_SKY;                  /* empty tiles: sky without noise */
        for (int k = 0; k < sc->n; k++) {
            long ox = (k % tiles) * SW_NX, oy = (k / tiles) * SW_NX;
            const float *src = sc->img + (size_t)k * SW_NPIX;
            for (long j = 0; j < SW_NX; j++)
                memcpy(img + (size_t)(oy + j) * nx + ox, src + (size_t)j * SW_NX,
                       SW_NX * sizeof *img);
        }
    }
    mp_card cards[] = {{"GAIN", 1.0, NULL, "e-/ADU"}, {"RDNOISE", SW_RON, NULL, "e-"},
                       {"EXPTIME", 1.0, NULL, "s"}, {"SKY", SW_SKY, NULL, "e-/px (truth)"}};
    snprintf(path, sizeof path, "%s/%s.fits", dir, sc->name);
    int rc = mp_image_write_float(path, img, nx, ny, cards, 4, err);
    if (img != sc->img)
        free(img);
    if (rc)
        return 1;
    snprintf(path, sizeof path, "%s/%s.truth", dir, sc->name);
    FILE *fp = fopen(path, "w");
    if (!fp) {
        snprintf(err, MP_ERRLEN, "%.400s: cannot write", path);
        return 1;
    }
    fprintf(fp, "# %s: x y flux mag sigmaE_crlb sigmaX_crlb x_start y_start (1-based pixels%s)\n",
            sc->name, sc->kind == SW_SINGLE ? " of the mosaic" : "");
    for (int k = 0; k < sc->n; k++) {
        const sw_truth *t = &sc->t[k];
        double ox = sc->kind == SW_SINGLE ? (double)((k % tiles) * SW_NX) : 0.0;
        double oy = sc->kind == SW_SINGLE ? (double)((k / tiles) * SW_NX) : 0.0;
        fprintf(fp, "%.6f %.6f %.6g %.6f %.6g %.6g %.6f %.6f\n", t->x + ox, t->y + oy, t->e, t->mag,
                t->se, t->sx, t->x0 + ox, t->y0 + oy);
    }
    if (ferror(fp) | fclose(fp)) {
        snprintf(err, MP_ERRLEN, "%.400s: write error", path);
        return 1;
    }
    mp_card pc[] = {{"OVERSAMP", sc->tab[0].os, NULL, "table elements per detector pixel"}};
    snprintf(path, sizeof path, "%s/%s_psf.fits", dir, sc->name);
    return mp_image_write(path, sc->tab[0].t, sc->tab[0].nx, sc->tab[0].ny, -64, pc, 1, err);
}
