"""Project exceptions.

Errors raised at the public boundary say what was wrong and what to change; inner
functions trust their inputs (see STYLE.md, rule 5).
"""


class RelightError(Exception):
    """Base class of every error this package raises on purpose."""


class InputError(RelightError, ValueError):
    """A file, argument or request that cannot be used as given.

    The message names the input and says what to change.
    """


class NumericalError(RelightError, ArithmeticError):
    """A computation produced a non-finite value that must not leave the function."""


class OutputError(RelightError, OSError):
    """A file that cannot be written (no space left, a read-only or missing folder, no
    permission). The message names the file and the system's reason; nothing partial is left."""


def os_reason(exc: OSError) -> str:
    """The system's reason of an OSError in words a message can end with ("no space left on
    device"), without the errno number."""
    import os

    text = exc.strerror or (os.strerror(exc.errno) if exc.errno else "") or str(exc)
    return text[:1].lower() + text[1:]
