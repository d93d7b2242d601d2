"""Finding a CMRT: the CMA-ES driver, its checkpoint codec, the evaluation backends, the batch memory bound
and the backend benchmark. Knows nothing of SQLite."""
