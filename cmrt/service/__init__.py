"""Runs kept and shared: the SQLite store, the job queue and its workers, queries, warm starts and
interpolation between known CMRTs."""
