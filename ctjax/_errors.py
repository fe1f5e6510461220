"""ctjax's exceptions: every user-facing failure is a `CtjaxError` (a `ValueError`)."""


class CtjaxError(ValueError):
    """Base class of every error ctjax raises on bad input.

    The message names the problem and, where there is one, the file. The command-line
    interface prints it on one line and exits with status 2.
    """


class CaptureError(CtjaxError):
    """A capture folder on disk is missing, malformed or inconsistent."""


class ParameterError(CtjaxError):
    """A parameter passed from Python is out of its domain (wrong shape, NaN, negative...)."""


class ReconstructionError(CtjaxError):
    """Structure-from-motion could not recover the shape (too few features, no initial pair)."""
