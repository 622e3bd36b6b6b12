/* segmented.c — the PSF of a segmented mirror from Fraunhofer diffraction
 * (issue 10: the diffraction-limited PSF that paper §5.4's Gaussian-derived
 * β ≥ 21 rule does not cover; design.md §6 "ugly PSF").
 *
 * The pupil is 18 hexagonal segments in two rings around a missing centre
 * one (JWST's layout), flat-to-flat width w with gaps of 0.02 w, sampled
 * on NPUP × NPUP points across its diameter D.  The intensity at angle ξ
 * (in λ/D) is |Σ_u P(u) exp(−2πi u·ξ)|², evaluated as two matrix products
 * (the kernel is separable even where the pupil is not), at SUB × SUB
 * points per table element and averaged: each element holds the light of
 * its (sub)pixel.  Monochromatic; normalised so that the whole plane sums
 * to 1 (Parseval: Σ|F|² over the plane = Σ P² · area), so a finite table
 * holds less.  A band [λ, λ(1 + band)] is NBAND such PSFs averaged (flat
 * spectrum): λ/D = lod px at its blue end, so the band's highest spatial
 * frequency is 1/lod cycles/px whatever its width. */
#include <complex.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include "sim/sim.h"

#define NPUP 96      /* pupil samples across D */
#define SUB 3        /* intensity samples per table element and axis */
#define NBAND 7      /* wavelengths across a band */

/* Inside a hexagon of flat-to-flat width w (flats on ±y) centred at 0. */
static int in_hex(double x, double y, double w)
{
    double h = 0.5 * w, ax = fabs(x), ay = fabs(y);
    return ay <= h && 0.5 * ay + 0.8660254037844386 * ax <= h;
}

/* The pupil: 18 segments, centres on the hexagonal lattice (rings 1, 2). */
static void pupil(double *P)
{
    const double pitch = 1.0 / 5.0;           /* D spans 5 segment pitches */
    const double w = pitch * 0.98;
    for (int j = 0; j < NPUP; j++)
        for (int i = 0; i < NPUP; i++) {
            double x = ((i + 0.5) / NPUP - 0.5), y = ((j + 0.5) / NPUP - 0.5), v = 0.0;
            for (int q = -2; q <= 2 && v == 0.0; q++)
                for (int r = -2; r <= 2 && v == 0.0; r++) {
                    int s = -q - r;
                    if (abs(s) > 2 || (q == 0 && r == 0))
                        continue;
                    /* Axial (q, r) to the centre of a flat-topped lattice. */
                    double cx = pitch * 0.8660254037844386 * q;
                    double cy = pitch * (r + 0.5 * q);
                    v = in_hex(x - cx, y - cy, w);
                }
            P[(size_t)j * NPUP + i] = v;
        }
}

/* Add weight × the monochromatic PSF at λ/D = lod px to t (nt × nt, h
 * elements a side of the centre). */
static int add_one(double lod, int os, int h, double weight, double *t, char *err)
{
    int nt = 2 * h + 1, m = nt * SUB;
    double *P = malloc(sizeof(double) * NPUP * NPUP);
    double complex *E = malloc(sizeof(double complex) * (size_t)m * NPUP);
    double complex *A = malloc(sizeof(double complex) * (size_t)NPUP * m);
    double complex *row = malloc(sizeof(double complex) * (size_t)m);
    int rc = 1;
    if (!P || !E || !A || !row) {
        snprintf(err, 256, "segmented PSF: out of memory");
        goto done;
    }
    pupil(P);
    double p2 = 0.0;
    for (int k = 0; k < NPUP * NPUP; k++)
        p2 += P[k];
    /* Sample a of the m per axis sits at (a + ½)/SUB − ½ − h elements from
     * the centre, in detector px /os, in λ/D /lod. */
    for (int a = 0; a < m; a++) {
        double xi = (((a + 0.5) / SUB - 0.5) - h) / os / lod;
        for (int u = 0; u < NPUP; u++)
            E[(size_t)a * NPUP + u] = cexp(-2.0 * M_PI * I * ((u + 0.5) / NPUP - 0.5) * xi);
    }
    /* A[v][a] = Σ_u P[v][u] E[a][u]: the x transform of every pupil row. */
    for (int v = 0; v < NPUP; v++)
        for (int a = 0; a < m; a++) {
            double complex s = 0.0;
            for (int u = 0; u < NPUP; u++)
                s += P[(size_t)v * NPUP + u] * E[(size_t)a * NPUP + u];
            A[(size_t)v * m + a] = s;
        }
    /* F[b][a] = Σ_v E[b][v] A[v][a]; |F|² averaged into its element.  The
     * plane's integral of |F|² dξ² is p2 (Parseval, pupil cell 1/NPUP²,
     * ξ cell 1/(os·lod·SUB)² per sample). */
    double norm = weight / (p2 * (double)NPUP * NPUP) / ((double)os * lod * os * lod * SUB * SUB);
    for (int b = 0; b < m; b++) {
        for (int a = 0; a < m; a++)
            row[a] = 0.0;
        for (int v = 0; v < NPUP; v++) {
            double complex e = E[(size_t)b * NPUP + v];
            const double complex *Av = A + (size_t)v * m;
            for (int a = 0; a < m; a++)
                row[a] += e * Av[a];
        }
        for (int a = 0; a < m; a++) {
            double re = creal(row[a]), im = cimag(row[a]);
            t[(size_t)(b / SUB) * nt + a / SUB] += (re * re + im * im) * norm;
        }
    }
    rc = 0;
done:
    free(P);
    free(E);
    free(A);
    free(row);
    return rc;
}

int mp_sim_segmented_psf(double lod, double band, int os, double radius, double **tab, int *n,
                         char *err)
{
    *tab = NULL;
    if (!(lod > 0) || !(band >= 0) || band > 2 || os < 1 || os > 16 || !(radius >= 1) ||
        radius > 200) {
        snprintf(err, 256, "segmented PSF: lambda/D %g px, band %g, OVERSAMP %d, radius %g px "
                 "out of range", lod, band, os, radius);
        return 1;
    }
    int h = (int)ceil(radius * os), nt = 2 * h + 1;
    double *t = calloc((size_t)nt * nt, sizeof *t);
    if (!t) {
        snprintf(err, 256, "segmented PSF: out of memory");
        return 1;
    }
    /* A flat band: NBAND wavelengths at the centres of equal slices. */
    int nb = band > 0 ? NBAND : 1;
    for (int k = 0; k < nb; k++)
        if (add_one(lod * (1.0 + band * (k + 0.5) / nb), os, h,
                    1.0 / nb, t, err)) {
            free(t);
            return 1;
        }
    *tab = t;
    *n = nt;
    return 0;
}
