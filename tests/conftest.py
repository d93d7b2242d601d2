import os

# Small matrices: BLAS threads only add overhead and nondeterministic scheduling.
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
