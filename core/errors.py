"""Exception families of ringlight.core.

Every error a user can cause (a bad file, a bad argument) is raised as one of these, with a
message that names the file and the problem in one line, so that the CLI can print it and exit 2
and the window can show it in a dialog. Long work reports through a :data:`ProgressCallback`,
which stops it by raising :class:`Cancelled`.
"""

from collections.abc import Callable


class RinglightError(Exception):
    """Base of every error ringlight reports to a user."""


class DatasetError(RinglightError):
    """An impulse dataset (manifest, frames, dark, mapping, cache) is missing or malformed."""


class StackError(RinglightError):
    """A ring light or transient stack was asked for with arguments the dataset cannot serve."""


class Cancelled(RinglightError):
    """Raised by a progress callback to stop long work; the work leaves nothing half-written."""


ProgressCallback = Callable[[float], None]
"""Called with the fraction of long work done (0 to 1); may raise :class:`Cancelled`."""
