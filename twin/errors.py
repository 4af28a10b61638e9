"""The one exception type users see: a one-line message naming what is wrong and what is allowed."""


class TwinError(ValueError):
    """Bad input or an impossible request; ``str(err)`` is a complete one-line message."""


class InfeasibleDesign(TwinError):
    """The LMI design has no solution; the message names the requirement to relax."""
