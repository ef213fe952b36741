"""Presets and options into stages (build), the stages run over a raw and written (run), the
sensor corrections a raw gets (corrections), the noise-adaptive demosaic choice (demosaic_choice)
and the skip planner (skip). The package's names are what ``clisp.pipeline`` always offered."""
from .build import (DEFAULT_HIGHLIGHTS, DEFAULT_PRESET, DEMOSAICS, EXPOSURE_LIMIT, HALF_SIZE_NO_DENOISE, PRESETS,
                    SKIP_WHERE_IT_PAYS, build_pipeline, chroma_denoise_for, denoise_params, make_demosaic,
                    resolve_options)
from .run import (DEFAULT_BUDGET, FILES_IN_FLIGHT, GPU_FILES_IN_FLIGHT, Pipeline, crop_of, output_size, process,
                  process_file, process_with_stats)

__all__ = ["DEFAULT_BUDGET", "DEFAULT_HIGHLIGHTS", "DEFAULT_PRESET", "DEMOSAICS", "EXPOSURE_LIMIT", "FILES_IN_FLIGHT",
           "GPU_FILES_IN_FLIGHT", "HALF_SIZE_NO_DENOISE", "PRESETS", "SKIP_WHERE_IT_PAYS", "Pipeline", "build_pipeline",
           "chroma_denoise_for", "crop_of", "denoise_params", "make_demosaic", "output_size", "process", "process_file",
           "process_with_stats", "resolve_options"]
