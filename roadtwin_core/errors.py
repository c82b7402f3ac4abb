"""One error type for everything a user can get wrong.

The CLI turns a :class:`RoadtwinError` into a single line on stderr and exit code 2, so every
message must name the file, prim or parameter at fault.
"""


class RoadtwinError(Exception):
    """Bad input or an impossible request; the message is shown to the user as is."""
