"""The errors of drawstring, by whose fault they are.

- :class:`InputError`: the user's input (a mesh, an option, a profile, a path) cannot be used;
  the command line prints its one-line message and exits with status 2.
- :class:`DesignError`: the input is valid but no design meets a hard target.
- :class:`InternalError`: one module handed another data that breaks its contract (a bug in
  drawstring, never the user's doing); the command line prints one line and exits with status 1.
"""


class InputError(ValueError):
    """Bad user input: a mesh, option or file the pipeline cannot work with.

    The message is one line that names the problem and what to do about it.
    """


class InternalError(RuntimeError):
    """Data passed between drawstring's own modules breaks the receiver's contract (a bug)."""


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
