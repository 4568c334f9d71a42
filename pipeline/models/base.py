"""The interface every robot model implements.

A model is a control-affine system x' = f(x) + g(x) u. It names its states and inputs, gives f, g
and the two Jacobians the stabilizer needs (df/dx and d(g(x) u)/dx), its parameters and limits.
Every method is vectorised over leading axes: ``x`` has shape (..., n), ``u`` (..., m), ``g(x)``
(..., n, m), the Jacobians (..., n, n).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from ..errors import InputError, require_positive
from ..geometry import wrap_angle
from ..limits import MIN_TURNING_RADIUS_M

#: the kinds of noise a run adds, each a level per state name (nhstab.execution.config.NoiseOptions)
NOISE_KINDS = ("initial", "sensor", "process")
#: the default noise of the pose states (x, y, theta): initial error std, sensor std, process
#: intensity [unit / sqrt(s)]
POSE_NOISE = {
    "initial": {"x": 0.10, "y": 0.10, "theta": 0.05},
    "sensor": {"x": 0.02, "y": 0.02, "theta": 0.01},
    "process": {"x": 0.02, "y": 0.02, "theta": 0.01},
}


def with_noise(base: dict, **levels: tuple[float, float, float]) -> dict:
    """``base`` (noise levels by kind, then state name) with more states: ``name=(initial, sensor,
    process)``; a new dict."""
    return {kind: {**base.get(kind, {}), **{name: v[i] for name, v in levels.items()}}
            for i, kind in enumerate(NOISE_KINDS)}


@dataclass(frozen=True)
class Model:
    """Base class. Subclasses set the class attributes and implement ``g`` and ``dgu_dx``."""

    name: str = field(default="", init=False)
    state_names: tuple[str, ...] = field(default=(), init=False)
    input_names: tuple[str, ...] = field(default=(), init=False)
    #: indices of states that are angles (errors in them are wrapped to [-pi, pi))
    angle_states: tuple[int, ...] = field(default=(), init=False)
    #: units of states and inputs, for file headers
    state_units: tuple[str, ...] = field(default=(), init=False)
    input_units: tuple[str, ...] = field(default=(), init=False)

    # ---- what nhstab knows of the model beyond its equations (one place per model) ----------------
    #: the built-in robot's description: footprint (a YAML footprint spec), planning margin [m],
    #: stabilizer defaults, planning turning radius (("fixed", metres) or ("factor", times the smallest
    #: turning radius)), and for a model that tows trailers the trailer's footprint
    robot_defaults: ClassVar[dict] = {

    }
    #: named robots of this model beside the built-in one: name -> a robot description (model parameters,
    #: footprint, ...; the keys of a ``robot:`` block other than ``model`` and ``name``), read with
    #: :func:`nhstab.robot.robot_preset`
    robot_presets: ClassVar[dict] = {}
    #: the default noise of a run (``nhstab run``, the tube): per kind (initial error std, sensor std,
    #: process intensity [unit / sqrt(s)]), a level per state name; a state not named has none
    noise_defaults: ClassVar[dict] = {kind: {} for kind in NOISE_KINDS}
    #: the (alpha, delta) grid of ``nhstab sweep``, which chose the stabilizer defaults (None: not swept)
    sweep_grid: ClassVar[dict | None] = None
    #: whether nhstab's planner plans for this model
    plannable: ClassVar[bool] = False
    #: the room [m] the geometric search keeps beyond the requested margin, so that the timed nominal
    #: still clears the margin (None where the model's planner keeps its own)
    search_pad: ClassVar[float | None] = None

    # ---- sizes -----------------------------------------------------------------------------
    @property
    def n(self) -> int:
        return len(self.state_names)

    @property
    def m(self) -> int:
        return len(self.input_names)

    # ---- dynamics --------------------------------------------------------------------------
    def f(self, x):
        """Drift vector field, shape (..., n). All built-in models are drift-free."""
        x = np.asarray(x, dtype=float)
        return np.zeros_like(x)

    def dfdx(self, x):
        """Jacobian of the drift, shape (..., n, n)."""
        x = np.asarray(x, dtype=float)
        return np.zeros(x.shape + (self.n,))

    def g(self, x):  # pragma: no cover - abstract
        """Input vector fields as columns, shape (..., n, m)."""
        raise NotImplementedError

    def dgu_dx(self, x, u):  # pragma: no cover - abstract
        """Jacobian of g(x) u with respect to x at fixed u, shape (..., n, n)."""
        raise NotImplementedError

    def rhs(self, x, u):
        """x' = f(x) + g(x) u, shape (..., n)."""
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        return self.f(x) + np.einsum("...ij,...j->...i", self.g(x), u)

    def linearize(self, x0, u0):
        """A = df/dx(x0) + d(g u0)/dx(x0) and B = g(x0) (Proposition 1)."""
        return self.dfdx(x0) + self.dgu_dx(x0, u0), self.g(x0)

    # ---- parameters and limits ---------------------------------------------------------------
    def params(self) -> dict:
        """Physical parameters and limits as a plain dict (recorded with every result)."""
        return {}

    def input_limits(self) -> np.ndarray:
        """(m, 2) array of [low, high] per input; +-inf where unlimited."""
        return np.tile([-np.inf, np.inf], (self.m, 1))

    def state_limits(self) -> np.ndarray:
        """(n, 2) array of [low, high] per state; +-inf where unlimited."""
        return np.tile([-np.inf, np.inf], (self.n, 1))

    @property
    def min_turning_radius(self) -> float:
        """The smallest radius [m] of a turn the planner may ask of the model's planned point: 0 for a
        model that turns in place (the base class's answer); the cars and the car_trailer give theirs.
        Every stage that needs it (the robot's planning radius, the planner's checks, the parking
        suite's geometry) asks the model."""
        return 0.0

    def state_error(self, x, x_ref):
        """e = x - x_ref with angle states wrapped to [-pi, pi)."""
        e = np.asarray(x, dtype=float) - np.asarray(x_ref, dtype=float)
        if self.angle_states:
            idx = list(self.angle_states)
            e[..., idx] = wrap_angle(e[..., idx])
        return e

    def describe(self) -> dict:
        return {"model": self.name, "state_names": list(self.state_names),
                "input_names": list(self.input_names), **self.params()}


def check_max_steer(model: str, wheelbase: float, max_steer: float) -> None:
    """A car's steering limit: at most atan(wheelbase / MIN_TURNING_RADIUS_M), so that its smallest
    turning radius wheelbase / tan(max_steer) is at least MIN_TURNING_RADIUS_M (:mod:`nhstab.limits`)."""
    top = math.atan(wheelbase / MIN_TURNING_RADIUS_M)
    if not max_steer <= top:
        raise InputError(f"{model}.max_steer", f"at most atan(wheelbase / {MIN_TURNING_RADIUS_M:g} m) = {top:.6g} rad "
                         f"(a turning radius wheelbase / tan(max_steer) of at least {MIN_TURNING_RADIUS_M:g} m)", max_steer)


def axle_turning_radius(wheelbase: float, steer: float) -> float:
    """A rear axle's turning radius L / tan(steer) [m] at the steering angle ``steer`` in (0, pi/2) (theta' =
    tan(phi) s / L for the rear axle's speed s): the one formula behind every car's turning radius."""
    return float(wheelbase / math.tan(steer))


def positive_param(name: str, value, model: str) -> float:
    """Validate a strictly positive finite model parameter (named ``model.name`` in errors)."""
    return require_positive(f"{model}.{name}", value)


def angle_limit(name: str, value, model: str, what: str = "") -> float:
    """Validate an angle limit of a model (a steering angle's, a hitch angle's): a positive angle below
    pi/2 rad, where its tangent is positive and finite (named ``model.name`` in errors)."""
    v = positive_param(name, value, model)
    if v >= math.pi / 2:
        raise InputError(f"{model}.{name}", f"a positive angle below pi/2 = {math.pi / 2:.4f} rad{what}", value)
    return v


class SteeredCar(Model):
    """What the cars with the steering angle ``phi`` as a state share (the subclasses declare the
    fields ``wheelbase``, ``max_speed``, ``max_steer``, ``max_steer_rate`` and their state order): the
    checks of those parameters, ``params``, the input limits (speed and steering rate) and the state
    limits (|phi| <= max_steer)."""

    #: the steering angle's noise: none initially or as process noise, a 0.005 rad sensor std
    noise_defaults: ClassVar[dict] = with_noise(POSE_NOISE, phi=(0.0, 0.005, 0.0))
    #: whether the speed input drives the front wheels (fwd_car: the body's speed is cos(phi) times it)
    #: rather than the rear axle (rwd_car)
    front_wheel_drive: ClassVar[bool] = False

    def turning_radius_at(self, steer: float) -> float:
        """The rear axle's turning radius L / tan(steer) [m] at a steering angle ``steer`` in (0, pi/2)."""
        return axle_turning_radius(self.wheelbase, steer)

    @property
    def min_turning_radius(self) -> float:
        """The rear axle's smallest turning radius L / tan(max_steer) [m] (theta' = tan(phi) s / L for
        the rear axle's speed s)."""
        return self.turning_radius_at(self.max_steer)

    def _check_car(self, name: str, state_names: tuple[str, ...]) -> None:
        """Check the car's parameters (errors name the model ``name``) and set its names: states in
        ``state_names`` order (x, y and the two angles theta, phi), inputs speed and steering rate."""
        for key in ("wheelbase", "max_speed", "max_steer_rate"):
            positive_param(key, getattr(self, key), name)
        angle_limit("max_steer", self.max_steer, name)
        check_max_steer(name, self.wheelbase, self.max_steer)
        for key, value in (("name", name), ("state_names", tuple(state_names)), ("input_names", ("v", "omega_s")),
                           ("angle_states", (2, 3)), ("state_units", ("m", "m", "rad", "rad")),
                           ("input_units", ("m/s", "rad/s"))):
            object.__setattr__(self, key, value)

    def params(self) -> dict:
        return {"wheelbase": self.wheelbase, "max_speed": self.max_speed,
                "max_steer": self.max_steer, "max_steer_rate": self.max_steer_rate}

    def input_limits(self) -> np.ndarray:
        return np.array([[-self.max_speed, self.max_speed], [-self.max_steer_rate, self.max_steer_rate]])

    def state_limits(self) -> np.ndarray:
        lim = np.tile([-np.inf, np.inf], (len(self.state_names), 1))
        lim[self.state_names.index("phi")] = [-self.max_steer, self.max_steer]
        return lim
