"""The one exception type that the CLI turns into a one-line message and exit code 2."""


class LayercamError(Exception):
    """A user-facing error: bad input, bad option, unwritable output.

    The CLI prints ``error: <message>`` on one line and exits with status 2; no traceback.
    """
