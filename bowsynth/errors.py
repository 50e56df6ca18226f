"""Errors a user can act on. The CLI prints them as one line; anything else is a bug."""


class BowsynthError(Exception):
    """A runtime failure with a message meant for the user (CLI exit code 1)."""

    exit_code = 1


class UsageError(BowsynthError):
    """Bad input from the user: a value, a path, a flag (CLI exit code 2)."""

    exit_code = 2


class SceneError(UsageError):
    """A scene value outside its allowed range."""


class ModelFileError(BowsynthError):
    """A model file that is missing, corrupt, foreign or of another format version."""


class DomainError(BowsynthError):
    """A scene or a rollout outside the domain a model was trained on."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread like Ctrl-C so that every cleanup path runs (finally blocks, temp files,
    training's checkpoint); the CLI exits 143 (130 for Ctrl-C)."""

    exit_code = 143


def interrupt_exit_code(e: BaseException) -> int:
    """The exit code for an interruption: 143 for SIGTERM, 130 for Ctrl-C."""
    return getattr(e, "exit_code", 130)
