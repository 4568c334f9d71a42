"""Robot models behind one interface, and the registry that maps names to them."""

from __future__ import annotations

import dataclasses

from ..errors import InputError, UnknownModelError
from .base import Model
from .car_trailer import CarTrailer
from .fwd_car import FwdCar
from .heisenberg import Heisenberg
from .rwd_car import RwdCar
from .unicycle import Unicycle

#: the registry: a model's name -> its class (the class holds everything nhstab knows of the model:
#: its equations, limits, state layout, built-in robot and whether the planner plans for it)
MODELS: dict[str, type[Model]] = {
    "unicycle": Unicycle,
    "rwd_car": RwdCar,
    "fwd_car": FwdCar,
    "heisenberg": Heisenberg,
    "car_trailer": CarTrailer,
}


def make_model(name: str, **params) -> Model:
    """Build a registered model by name with keyword parameters (e.g. ``wheelbase=1.0``)."""
    try:
        cls = MODELS[name]
    except (KeyError, TypeError):
        raise UnknownModelError("model", "one of " + ", ".join(sorted(MODELS)), name) from None
    allowed = {f.name for f in dataclasses.fields(cls) if f.init}
    for key in params:
        if key not in allowed:
            expected = ("one of " + ", ".join(sorted(allowed))) if allowed else "no parameters"
            raise InputError(f"{name} parameter", expected, key)
    return cls(**params)


__all__ = ["MODELS", "Model", "make_model", "Heisenberg", "Unicycle", "FwdCar", "RwdCar", "CarTrailer"]
