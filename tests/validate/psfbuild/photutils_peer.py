"""photutils_peer.py -- photutils (Debian's python3-photutils) on a
psfbuild.sh frame, as its documentation's PSF photometry reads: the sky
(MMMBackground) taken off, stars found by DAOStarFinder at 4 sigma, an
effective PSF built from the frame's bright isolated stars (extract_stars,
EPSFBuilder at oversampling OS), then DAOPhotPSFPhotometry (the
DAOPHOT-like iterative find, group, fit and subtract, two passes).  Prints
"x y flux" lines (1-based pixels, the flux in the frame's units) for
peers.sh to score with psfb match.

    /usr/bin/python3 photutils_peer.py FRAME[EXT] FWHM [OS]      (OS: 2)
"""
import sys
import warnings

import numpy as np
from astropy.io import fits
from astropy.modeling.fitting import LevMarLSQFitter
from astropy.nddata import NDData
from astropy.stats import sigma_clipped_stats
from astropy.table import Table
from photutils.background import MMMBackground
from photutils.detection import DAOStarFinder
from photutils.psf import DAOPhotPSFPhotometry, EPSFBuilder, extract_stars

warnings.simplefilter("ignore")

frame, fwhm = sys.argv[1], float(sys.argv[2])
OS = int(sys.argv[3]) if len(sys.argv) > 3 else 2
ext = 0                         # "f.fits[SCI]", "f.fits[1]": that HDU
if frame.endswith("]") and "[" in frame:
    frame, ext = frame[:-1].split("[", 1)
    ext = int(ext) if ext.isdigit() else ext
data = fits.getdata(frame, ext).astype(float)
sky = MMMBackground()(data)
_, _, sigma = sigma_clipped_stats(data, sigma=3.0)
img = data - sky

# Stars: 4 sigma, as the other peers find them.
found = DAOStarFinder(threshold=4.0 * sigma, fwhm=fwhm)(img)

# PSF stars: the brightest that have no other detection within 4 FWHM
# and are 12 px from the edges (the cut-outs are 25 px, as PSFEx's), at
# most 60 (pstselect's number in peers.sh).
size = 25
x, y, peak = (np.asarray(found[c]) for c in ("xcentroid", "ycentroid", "peak"))
ny, nx = img.shape
keep = []
for i in np.argsort(-peak):
    d = np.hypot(x - x[i], y - y[i])
    if (np.sum(d < 4.0 * fwhm) == 1 and size // 2 < x[i] < nx - 1 - size // 2
            and size // 2 < y[i] < ny - 1 - size // 2):
        keep.append(i)
    if len(keep) == 60:
        break
stars_tbl = Table({"x": x[keep], "y": y[keep]})
stars = extract_stars(NDData(data=img), stars_tbl, size=size)
epsf, _ = EPSFBuilder(oversampling=OS, maxiters=10, progress_bar=False)(stars)

# PSF photometry: DAOPHOT's scheme (groups within 2 FWHM fitted together,
# the residual searched again), fitting 2 FWHM + 1 px boxes (odd).
fit = int(2 * round(fwhm)) + 1
phot = DAOPhotPSFPhotometry(crit_separation=2.0 * fwhm, threshold=4.0 * sigma, fwhm=fwhm,
                            psf_model=epsf, fitshape=(fit, fit), fitter=LevMarLSQFitter(),
                            niters=2, aperture_radius=1.5 * fwhm)
res = phot(image=img)
for r in res:
    if np.isfinite(r["flux_fit"]):
        print(f"{r['x_fit'] + 1:.5f} {r['y_fit'] + 1:.5f} {r['flux_fit']:.6g}")
