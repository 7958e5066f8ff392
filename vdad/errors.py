"""Exceptions raised by vdad.

Every error a user can provoke with bad input is a :class:`VdadError`, and its
message names the body, joint or argument at fault.
"""


class VdadError(Exception):
    """Base class of every error raised by vdad."""


class ModelError(VdadError, ValueError):
    """A model description is invalid (names the offending body or joint)."""


class InputError(VdadError, ValueError):
    """An argument has the wrong shape or holds a non-finite value."""


class UnsupportedFeatureError(VdadError):
    """An imported model uses a feature that vdad does not model."""


class SimulationError(VdadError, RuntimeError):
    """A simulation blew up; the message names the step and the cause."""


class RenderError(VdadError, RuntimeError):
    """A rendered method could not start or run (no EGL/OpenGL); the message says
    what to install or set."""
