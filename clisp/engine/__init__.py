"""The engine: the OpenCL runtime (context, programs, buffers), the tile plan, streaming, memory metering and profiling."""
