"""User-facing errors. The CLI prints `str(err)` on one line and exits with `err.exit_code`."""


class UserError(Exception):
    """Bad input or an impossible request: one line for the user, never a traceback."""

    exit_code = 1


class InputError(UserError):
    """A file, path or value the user gave cannot be used (missing folder, wrong kind of file, out of range)."""

    exit_code = 2


class ParamError(UserError):
    """A parameter file or --set override is wrong (unknown/missing key, type, value). key: the "section.key" whose
    value is wrong, when one is (None: the file itself, or a key that does not exist)."""

    exit_code = 2

    def __init__(self, message: str, key: str | None = None):
        super().__init__(message)
        self.key = key


class DesignRefused(UserError):
    """The design would not stabilize the sampled loop (or cannot be computed)."""

    exit_code = 3

    @property
    def why(self) -> str:
        """The reason alone, without the "design refused: " its messages begin with."""
        return str(self).removeprefix("design refused: ")
