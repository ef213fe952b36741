"""The programs: the command line (cli), batch runs on Dask (batch), the built-in sample
(demo), kernel warm-up (warm) and the numerical stress tests (stress)."""
