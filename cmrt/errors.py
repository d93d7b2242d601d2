"""The one exception type users see: bad input that the CLI turns into exit code 2."""


class CmrtError(ValueError):
    """Bad user input (unknown task, bad value, unreadable file, ...).

    The message is a single line meant for the user; the CLI prints it without a
    traceback and exits with status 2.
    """


class TransientFault(RuntimeError):
    """A fault of the machine, not of the input or the code: a full disk, a lost dask or loky worker, a
    SIGTERM. The worker gives the run back to the queue (it resumes from its last checkpoint) up to
    ``cmrt.store.MAX_RETRIES`` times, then marks it failed with the reason."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, SIGHUP or SIGQUIT, turned into an exception so that a worker gives its run back before exiting
    (like Ctrl-C); ``signum`` is the signal (the exit status is 128 + it)."""

    def __init__(self, signum: int = 15):
        super().__init__(signum)
        self.signum = signum
