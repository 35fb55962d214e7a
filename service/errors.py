"""The exception types the command line turns into a one-line reason and a non-zero exit."""


class CliError(Exception):
    """Bad input or a failed step that the user can act on; the message is the whole story."""
