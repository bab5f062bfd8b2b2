"""The one exception type for mistakes a user can fix: a bad path, option, column or file.

``lead-s2r`` catches :class:`UserError` in ``main()`` and prints its message as one line with exit status 2
(``--debug`` shows the traceback instead); anything else is a bug and keeps its traceback. Raise it from
anywhere (a verb, a scorer, a datamodule, an adapter's ``list_logs``) with a message that names the file, key,
field or option and says what to do. Domain errors (``SchemaError``, ``PredictionError``, adapters' format
errors) derive from it, so callers of the Python API can still catch them by their own names.
This module imports nothing, so every layer (``schema.py`` included) may use it.
"""

from collections.abc import Iterable

#: How many names an error message lists before "...".
LISTED = 10


class UserError(Exception):
    """Bad input a user can fix; the message names what is wrong and where, and says what to do."""

    def one_line(self) -> str:
        """The message on one line, as ``main()`` prints it."""
        return " ".join(str(self).split())


def listing(names: Iterable[str]) -> str:
    """``a, b, c`` (the first :data:`LISTED`, sorted), then ``... (N in all)`` if there are more: the one way a
    message lists what is missing, however many there are."""
    names = sorted(names)
    shown = ", ".join(names[:LISTED])
    return shown if len(names) <= LISTED else f"{shown} ... ({len(names)} in all)"
