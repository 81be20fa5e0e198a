"""The one family of user errors: bad input, arguments, files or setups.

Every error a user can cause is a :class:`SpotnavError` with a one-line message
that names what to change; the command line turns it into
``spotnav: error: MESSAGE`` and exit code 2. Anything else that escapes is a
bug and keeps its traceback. A frame that cannot be localized is not an error:
it is a :class:`~spotnav.pose.estimate.PoseEstimate` with a status.
"""

from __future__ import annotations

__all__ = ["InputError", "SpotnavError"]


class SpotnavError(Exception):
    """A user error (see the module's docstring)."""


class InputError(SpotnavError):
    """A file, argument or set of frames that cannot be used as given."""
