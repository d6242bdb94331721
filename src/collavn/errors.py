"""Errors and warnings raised by collavn; each names the problem and the object it concerns."""


class CollavnError(Exception):
    """Base class for every error collavn raises on bad input."""


class SceneError(CollavnError, ValueError):
    """A scene cannot be loaded, built or navigated (missing file, no floor, ...)."""


class RenderError(CollavnError, ValueError):
    """A render request is invalid (NaN pose, unknown backend, empty batch, ...)."""


class ActionError(CollavnError, ValueError):
    """An action is malformed (wrong shape, NaN or inf)."""


class DatasetError(CollavnError, ValueError):
    """An episode file is corrupt, edited, or does not match its scene."""


class CheckpointError(CollavnError, ValueError):
    """A checkpoint is unreadable or was written by a different configuration."""


class ConfigError(CollavnError):
    """A configuration value, a command-line argument or a saved configuration is invalid.

    Deliberately not a ``ValueError``: tyro turns ``ValueError``s raised while it builds
    a config into its own message box, while a ``CollavnError`` reaches the ``collavn``
    dispatcher, which prints every refused argument the same way
    (``collavn: error: …``, exit 2).
    """


class Interrupted(BaseException):
    """A second SIGINT/SIGTERM: stop at once, without saving (see ``training.trainer``).

    Attributes:
        signum: The signal number (the process exits with ``128 + signum``).
    """

    def __init__(self, signum: int, message: str) -> None:
        super().__init__(message)
        self.signum = signum


class CollavnWarning(UserWarning):
    """Base class for warnings: the input was usable but probably not what was meant."""


class SceneWarning(CollavnWarning):
    """A scene loaded but looks wrong (up axis, unit, missing textures, off-map pose)."""
