"""The exception tree of nhstab.

Every expected failure raises a :class:`PipelineError`. Errors caused by bad input also subclass
:class:`ValueError` and name the offending argument, what was expected and what was given, so the
command line can print them as one line.
"""

from __future__ import annotations

import contextlib
import re


class PipelineError(Exception):
    """Base class of every error nhstab raises on purpose."""


class NhstabWarning(UserWarning):
    """Base class of the warnings nhstab issues on purpose (the command line prints each as one line)."""


class NotStabilizingWarning(NhstabWarning):
    """A requested feedback law is not stabilizing in general (the past window of Remark 2)."""


class InputError(PipelineError, ValueError):
    """An argument, option or file content is not acceptable.

    ``argument`` names the argument or key; the message says what was expected and what was given.
    Text that YAML 1.1 reads as a string although it looks like a number (``1e9``), given alone or in
    a list or mapping, gets the shared hint on how to write it (:func:`number_hint`),
    whichever check refused it.
    """

    def __init__(self, argument: str, expected: str, got: object | None = None, *, detail: str = ""):
        hint = _number_hint(got)
        if hint and hint not in detail:
            detail = f"{detail}; {hint}" if detail else hint
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

    def renamed(self, argument: str, **changes) -> "InputError":
        """The same error (its class, what was expected, what was given, the detail) naming
        ``argument`` instead: how a caller that knows the key the user wrote names it. ``changes``
        replace ``expected``, ``got`` or ``detail``."""
        fields = {"expected": self.expected, "got": self.got, "detail": self.detail, **changes}
        return type(self)(argument, fields["expected"], fields["got"], detail=fields["detail"])

    def __reduce__(self):
        # pickled by its fields, so that it crosses from a worker process (local or Dask) intact
        return (_rebuild_input_error, (type(self), self.argument, self.expected, self.got, self.detail))


def _rebuild_input_error(cls, argument, expected, got, detail):
    return cls(argument, expected, got, detail=detail)


def number_hint(value) -> str:
    """For text that YAML 1.1 leaves as a string although it looks like a number in exponent form
    (``1e9``, ``5E-3``): a hint on how to write it; else ""."""
    if isinstance(value, str) and re.fullmatch(r"\s*[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+\s*", value):
        mant, _, exp = value.strip().lower().partition("e")
        # YAML 1.1's float needs a dot in the mantissa, a digit before it when signed, and a sign in the
        # exponent
        sign, digits = (mant[0], mant[1:]) if mant[0] in "+-" else ("", mant)
        digits = ("0" + digits if digits.startswith(".") else digits) if "." in digits else digits + ".0"
        fixed = sign + digits + "e" + (exp if exp[0] in "+-" else "+" + exp)
        return f"YAML 1.1 reads {value.strip()} as text: write {fixed}"
    return ""


def _number_hint(got, depth: int = 0) -> str:
    """The YAML 1.1 number hint for the first number-looking text in ``got`` (text, or a list or
    mapping of values as a YAML file gives them), or ""."""
    if isinstance(got, str):
        return number_hint(got)
    if depth < 3 and isinstance(got, (list, tuple, dict)):
        items = got.values() if isinstance(got, dict) else got
        for i, v in enumerate(items):
            if i >= 64:
                break
            hint = _number_hint(v, depth + 1)
            if hint:
                return hint
    return ""


@contextlib.contextmanager
def user_keys(names: dict):
    """Name the keys the user wrote. Inside the block, an :class:`InputError` whose argument is a key
    of ``names`` (the name a validator knows, e.g. ``delta`` or ``controller.gamma``), or starts with
    one followed by ``[`` or ``.``, is raised again naming ``names[key]`` instead (e.g. ``--delta``,
    ``grid.delta[0]``, ``car.yaml: robot.stabilizer.delta``), with everything else it says kept; a
    key below it follows (``noise.initial`` -> ``--initial-error`` names ``noise.initial.x`` as
    ``--initial-error x``). A value may also be (user key, the value the user wrote), where the value
    checked was derived from it (``--headroom`` scales ``max_speed``). A value of None leaves that key
    as it is. Blocks nest: the innermost that knows a key names it."""
    try:
        yield
    except InputError as exc:
        new = _user_key(exc.argument, names)
        if new is None:
            raise
        name, got = new
        raise (exc.renamed(name) if got is _SAME else exc.renamed(name, got=got)) from None


_SAME = object()


def _user_key(argument, names: dict):
    """(user key, value or _SAME) for ``argument``, or None."""
    if not isinstance(argument, str):
        return None
    given = {key: (user if isinstance(user, tuple) else (user, _SAME)) for key, user in names.items()
             if user is not None}
    if argument in given:
        return given[argument]
    for key, (user, got) in given.items():
        rest = argument[len(key):]
        if argument.startswith(key) and rest[:1] in ("[", "."):
            return (user + " " + rest[1:] if user.startswith("-") and rest[0] == "." else user + rest), got
    return None


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
