"""The one exception type users see: bad input that the CLI turns into exit code 2."""


class CmrtError(ValueError):
    """Bad user input (unknown task, bad value, unreadable file, ...).

    The message is a single line meant for the user; the CLI prints it without a
    traceback and exits with status 2.
    """


class TransientFault(RuntimeError):
    """A fault of the machine, not of the input or the code: a full disk, a lost dask or loky worker, a
    SIGTERM. The worker gives the run back to the queue (it resumes from its last checkpoint) up to
    ``cmrt.service.store.MAX_RETRIES`` times, then marks it failed with the reason."""


class DiskFull(TransientFault):
    """The disk holding the store (or a file cmrt writes) is full: said as "disk full" everywhere, exit 75; a
    worker gives its run back to the queue before it stops."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, SIGHUP or SIGQUIT, turned into an exception so that a worker gives its run back before exiting
    (like Ctrl-C); ``signum`` is the signal (the exit status is 128 + it)."""

    def __init__(self, signum: int = 15):
        super().__init__(signum)
        self.signum = signum


_received: list[int] = []  # terminating signals received by this process (cmrt.cli's handler notes them)


def note_signal(signum: int) -> None:
    """Record a terminating signal before its handler raises :class:`Terminated`: raised inside an SQLite
    progress callback, the exception is swallowed by sqlite3 and the step fails as "interrupted"; whoever
    catches that failure asks :func:`pending_termination` and stops as the signal asked."""
    _received.append(signum)


def pending_termination() -> Terminated | None:
    """The termination a received signal asked for (None if none arrived)."""
    return Terminated(_received[-1]) if _received else None


def clear_signals() -> None:
    _received.clear()
