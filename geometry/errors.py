"""Errors that the command line turns into a one-line message and exit status 2."""


class InputError(ValueError):
    """Bad user input: a mesh, option or file the pipeline cannot work with.

    The message is one line that names the problem and what to do about it.
    """


class DesignError(RuntimeError):
    """The input was valid but the design cannot meet its targets (reported, exit status 3)."""
