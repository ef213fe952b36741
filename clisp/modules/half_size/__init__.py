"""Half-size binning (--half-size): one pixel per 2 x 2 block of the mosaic, no demosaic."""
