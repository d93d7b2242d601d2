"""The one exception type users see: bad input that the CLI turns into exit code 2."""


class CmrtError(ValueError):
    """Bad user input (unknown task, bad value, unreadable file, ...).

    The message is a single line meant for the user; the CLI prints it without a
    traceback and exits with status 2.
    """
