"""The simulator: scenes (sRGB or spectral) to noisy LMS or Bayer raws: optics, noise, spectra, charts, colorimetry."""
