"""Errors that the command line turns into a one-line message and exit status 2."""


class InputError(ValueError):
    """Bad user input: a mesh, option or file the pipeline cannot work with.

    The message is one line that names the problem and what to do about it.
    """


class DesignError(RuntimeError):
    """The input was valid but the design cannot meet its targets (reported, exit status 3)."""


class ThicknessError(DesignError):
    """Tiles this thick turn inside out where the target curves tighter than the thickness.

    Attributes
    ----------
    thickness : float, mm
        The thickness asked for.
    inverted : int
        Tiles turned inside out.
    advice : float, mm
        A thickness that works on this tiling (0 when none was found).
    """

    def __init__(self, message: str, thickness: float, inverted: int, advice: float) -> None:
        super().__init__(message)
        self.thickness = thickness
        self.inverted = inverted
        self.advice = advice
