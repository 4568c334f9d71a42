"""The exception tree of nhstab.

Every expected failure raises a :class:`PipelineError`. Errors caused by bad input also subclass
:class:`ValueError` and name the offending argument, what was expected and what was given, so the
command line can print them as one line.
"""

from __future__ import annotations


class PipelineError(Exception):
    """Base class of every error nhstab raises on purpose."""


class NhstabWarning(UserWarning):
    """Base class of the warnings nhstab issues on purpose (the command line prints each as one line)."""


class NotStabilizingWarning(NhstabWarning):
    """A requested feedback law is not stabilizing in general (the past window of Remark 2)."""


class InputError(PipelineError, ValueError):
    """An argument, option or file content is not acceptable.

    ``argument`` names the argument or key; the message says what was expected and what was given.
    """

    def __init__(self, argument: str, expected: str, got: object | None = None, *, detail: str = ""):
        self.argument = argument
        self.expected = expected
        self.got = got
        self.detail = detail
        msg = f"'{argument}' must be {expected}"
        if got is not None:
            msg += f"; got {_short(got)}"
        if detail:
            msg += f" ({detail})"
        super().__init__(msg)

    def __reduce__(self):
        # pickled by its fields, so that it crosses from a worker process (local or Dask) intact
        return (_rebuild_input_error, (type(self), self.argument, self.expected, self.got, self.detail))


def _rebuild_input_error(cls, argument, expected, got, detail):
    return cls(argument, expected, got, detail=detail)


class UnknownModelError(InputError):
    """The robot model name is not registered."""


class TrajectoryError(InputError):
    """A nominal trajectory is malformed (shapes, NaN, non-increasing time, too short)."""


class SingularGramianError(PipelineError):
    """The weighted controllability gramian is (numerically) singular somewhere on the trajectory.

    The law of Proposition 1 needs H_c(t, t + delta) uniformly invertible; this error says where it
    is not: ``time`` (s), the smallest eigenvalue ``min_eigenvalue`` and the numerical ``rank``.
    """

    def __init__(self, time: float, min_eigenvalue: float, rank: int, n: int, threshold: float, window: str):
        self.time = float(time)
        self.min_eigenvalue = float(min_eigenvalue)
        self.rank = int(rank)
        self.n = int(n)
        self.threshold = float(threshold)
        self.window = window
        super().__init__(
            f"the {window}-window gramian is singular at t = {self.time:.6g} s: smallest eigenvalue "
            f"{self.min_eigenvalue:.3e} <= threshold {self.threshold:.3e}, numerical rank {self.rank} of {self.n}; "
            "the trajectory is not uniformly controllable over windows of length delta (does the robot stop?)"
        )


class NumericalError(PipelineError):
    """A computation produced non-finite values or failed to converge."""


def require_finite(name: str, value) -> float:
    """``value`` as a finite float, or an InputError naming ``name``."""
    import math

    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(name, "a finite number", value) from None
    if not math.isfinite(v):
        raise InputError(name, "a finite number", value)
    return v


def require_positive(name: str, value) -> float:
    """``value`` as a positive finite float, or an InputError naming ``name``."""
    import math

    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(name, "a positive finite number", value) from None
    if not math.isfinite(v) or v <= 0:
        raise InputError(name, "a positive finite number", value)
    return v


def _short(value: object, limit: int = 80) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."
