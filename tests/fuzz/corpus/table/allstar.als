#K IRAF       = CommunityIRAFV2.17      version    %-23s     
#K HOST       = vm                      computer   %-23s     
#K DATE       = 2026-12-07              yyyy-mm-dd %-23s     
#K TIME       = 07:11:38                hh:mm:ss   %-23s     
#K PACKAGE    = daophot                 name       %-23s     
#K TASK       = allstar                 name       %-23s     
#K IMAGE      = im.fits                 imagename  %-23s     
#K PHOTFILE   = im.mrg2                 filename   %-23s     
#K PSFIMAGE   = im.dpsf                 imagename  %-23s     
#K ALLSTARFIL = im.als2                 filename   %-23s     
#K REJFILE    = im.arj2                 filename   %-23s     
#K SUBIMAGE   = im.sub2                 imagename  %-23s     
#K SCALE      = 1.                      units/pix  %-23.7g   
#K DATAMIN    = INDEF                   counts     %-23.7g   
#K DATAMAX    = INDEF                   counts     %-23.7g   
#K GAIN       = 1.                      e-/adu     %-23.7g   
#K READNOISE  = 3.                      electrons  %-23.7g   
#K OTIME      = INDEF                   timeunit   %-23s     
#K XAIRMASS   = INDEF                   number     %-23.7g   
#K IFILTER    = INDEF                   filter     %-23s     
#K RECENTER   = yes                     switch     %-23b     
#K GRPSKY     = yes                     switch     %-23b     
#K FITSKY     = yes                     switch     %-23b     
#K PSFMAG     = -14.744                 magnitude  %-23.7g   
#K PSFRAD     = 12.                     scaleunit  %-23.7g   
#K FITRAD     = 3.                      scaleunit  %-23.7g   
#K ANNULUS    = 3.                      scaleunit  %-23.7g   
#K DANNULUS   = 11.                     scaleunit  %-23.7g   
#K MAXITER    = 50                      number     %-23d     
#K MAXGROUP   = 60                      number     %-23d     
#K FLATERROR  = 0.75                    percentage %-23.7g   
#K PROFERROR  = 5.                      percentage %-23.7g   
#K CLIPEXP    = 6                       number     %-23d     
#K CLIPRANGE  = 2.5                     sigma      %-23.7g   
#K MERGERAD   = INDEF                   scaleunit  %-23.7g   
#
#N ID    XCENTER   YCENTER   MAG         MERR          MSKY           NITER    \
#U ##    pixels    pixels    magnitudes  magnitudes    counts         ##       \
#F %-9d  %-10.3f   %-10.3f   %-12.3f     %-14.3f       %-15.7g        %-6d      
#
#N         SHARPNESS   CHI         PIER  PERROR                                \
#U         ##          ##          ##    perrors                               \
#F         %-23.3f     %-12.3f     %-6d  %-13s                                  
#
1        21.152    19.481    -13.144     0.017         98.24342       4        \
           -0.152      2.634       0     No_error                               
3        120.600   21.943    -14.745     0.002         96.01369       4        \
           0.002       0.229       0     No_error                               
2        228.452   21.092    -10.491     0.008         100.1648       4        \
           0.036       0.648       0     No_error                               
6        235.694   42.040    -9.282      0.022         100.2732       4        \
           0.056       1.057       0     No_error                               
