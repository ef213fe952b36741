"""Demosaic studies: Bayer RCD, GBTF and their combination (NumPy, bayer_numpy's helpers) measured
against the shipped demosaics in docs/RESULTS.md (tools/demosaic_study.py), and a
residual-interpolation LMS demosaic (lms_ri; tools/bench_demosaic_quality.py --lms-numpy)."""
