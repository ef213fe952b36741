"""Studies outside the installed package: code that no preset or CLI path reaches, kept because
docs/RESULTS.md measures it and tools/ and tests/ still run it (import it from a checkout's root:
``from research.demosaic import bayer_rcd``)."""
