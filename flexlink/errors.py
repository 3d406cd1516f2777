"""Errors that reach the user as one clear message (never a traceback)."""


class FlexlinkError(Exception):
    """Base class: the CLI prints ``str(error)`` and exits non-zero."""


class SceneError(FlexlinkError):
    """A scene file that is wrong: the message names the file, the key and what is expected."""


class BuildError(FlexlinkError):
    """Code generation, compilation or packaging of an FMU failed."""
