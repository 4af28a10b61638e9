"""The one exception type users see: a one-line message naming what is wrong and what is allowed."""


class TwinError(ValueError):
    """Bad input or an impossible request; ``str(err)`` is a complete one-line message."""


class InfeasibleDesign(TwinError):
    """The LMI design has no solution; the message names the requirement to relax."""


class PluginError(TwinError):
    """A controller or estimator (built-in or a user's) broke its contract
    (:mod:`twin.protocols`): could not be loaded, lacks a method, or returned a value of
    the wrong shape or a non-finite one. The message names the object and what was expected."""
