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
