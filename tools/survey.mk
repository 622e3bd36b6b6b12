# survey.mk — every frame of a survey as a make target, N at a time:
#
#   make -j16 -f tools/survey.mk LIST=frames.lis PARAMS='psf=psf.fits'
#
# builds frame.cat (and the pipeline's other outputs) for every frame of the
# @list LIST (blank and '#' lines skipped, as matphot reads lists), one
# `matphot pipeline` per frame with one OpenMP thread each (THREADS).  A
# frame whose catalog exists is not run again, so after a crash or an
# interrupt the same command does only what is missing: outputs are written
# to hidden temporaries and renamed, never left half-written.  MATPHOT names
# the binary.  FRAMES='a.fits b.fits' instead of LIST names the frames.
MATPHOT ?= matphot
THREADS ?= 1
PARAMS  ?=
LIST    ?=
FRAMES  ?= $(if $(LIST),$(shell sed -e 's/\r$$//' -e 's/^[[:space:]]*//' \
                -e 's/[[:space:]]*$$//' -e '/^\#/d' -e '/^$$/d' $(LIST)))
CATS    := $(patsubst %.fits,%.cat,$(filter %.fits,$(FRAMES)))

.PHONY: all
all: $(CATS)

%.cat: %.fits
	OMP_NUM_THREADS=$(THREADS) $(MATPHOT) pipeline $< $(PARAMS)
