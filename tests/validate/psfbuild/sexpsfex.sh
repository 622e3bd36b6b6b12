# sexpsfex.sh — SExtractor → PSFEx → SExtractor's PSF fit, the one chain
# of the SExtractor + PSFEx peer (sourced by tests/validate/psfbuild/peers.sh
# on the simulated scenes and tests/bench/real/real.sh on the real frames).
#
# sexpsfex_chain DIR FRAME GAIN SATUR FWHM DEGREE TIMER: in DIR (FRAME an
# absolute path), SExtractor at 4 sigma (no filter, minarea 3; apertures of
# 3 FWHM, the 1.5-FWHM radius DAOPHOT's photometry uses, which PSFEx
# normalises its model to) writes vignets, PSFEx builds its model at its
# own sampling with PSFVAR_DEGREES DEGREE, and SExtractor fits it: psf.cat
# (ASCII_HEAD: NUMBER XPSF_IMAGE YPSF_IMAGE FLUX_PSF FLUXERR_PSF MAG_PSF
# MAGERR_PSF CHI2_PSF ERRX2PSF_IMAGE ERRY2PSF_IMAGE FLAGS).  Each of the
# three runs is timed by "TIMER OUT CMD..." into DIR/t1, t2, t3.  Needs SEX
# (source-extractor or sex).  Nonzero on failure, its logs in DIR.
sexpsfex_chain() {
    (
        cd "$1" || exit 1
        dia=$(awk -v f="$5" 'BEGIN { printf "%.1f", 3 * f }')
        printf '%s\n' X_IMAGE Y_IMAGE XWIN_IMAGE YWIN_IMAGE FLUX_APER FLUXERR_APER FLUX_RADIUS \
            ELONGATION FLAGS SNR_WIN FLUX_MAX 'VIGNET(25,25)' > pre.param
        printf '%s\n' NUMBER XPSF_IMAGE YPSF_IMAGE FLUX_PSF FLUXERR_PSF MAG_PSF MAGERR_PSF \
            CHI2_PSF ERRX2PSF_IMAGE ERRY2PSF_IMAGE FLAGS > psf.param
        common="-GAIN $3 -SATUR_LEVEL $4 -FILTER N -DETECT_THRESH 4 -DETECT_MINAREA 3 \
-BACK_SIZE 64 -PHOT_APERTURES $dia -SEEING_FWHM $5 -PIXEL_SCALE 1 -VERBOSE_TYPE QUIET \
-CHECKIMAGE_TYPE NONE -WRITE_XML N"
        # shellcheck disable=SC2086
        "$7" t1 "$SEX" "$2" $common -PARAMETERS_NAME pre.param -CATALOG_TYPE FITS_LDAC \
            -CATALOG_NAME pre.cat > sex1.log 2>&1 &&
        "$7" t2 psfex pre.cat -PSFVAR_DEGREES "$6" -PSFVAR_KEYS X_IMAGE,Y_IMAGE -PSF_SIZE 25,25 \
            -PSF_SAMPLING 0 -PHOTFLUX_KEY 'FLUX_APER(1)' -PHOTFLUXERR_KEY 'FLUXERR_APER(1)' \
            -CHECKPLOT_TYPE NONE -CHECKIMAGE_TYPE NONE -WRITE_XML N -VERBOSE_TYPE NORMAL \
            > psfex.log 2>&1 &&
        # shellcheck disable=SC2086
        "$7" t3 "$SEX" "$2" $common -PSF_NAME pre.psf -PARAMETERS_NAME psf.param \
            -CATALOG_TYPE ASCII_HEAD -CATALOG_NAME psf.cat > sex2.log 2>&1
    )
}
