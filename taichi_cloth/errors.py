"""Errors that the command line turns into exit codes (README, "Exit codes")."""


class InputError(Exception):
    """Bad input: a scene file, key, flag or path the user can fix. Exit code 2.

    The message is one line and names the file, key or flag.
    """

    exit_code = 2


class UnstableError(Exception):
    """The simulation could not be kept stable. Exit code 3.

    The message names the frame, the integrator and dt, and says what to change.
    """

    exit_code = 3

    def __init__(self, message: str, frame: int):
        super().__init__(message)
        self.frame = frame
