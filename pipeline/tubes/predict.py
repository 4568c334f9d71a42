"""The error tube of a feedback law under a noise model: the linear tube where it holds, else the sampled one."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errors import InputError, NumericalError
from ..geometry import Footprint
from ..limits import check_probability
from .base import (
    DEFAULT_CONFIDENCE,
    DEFAULT_DISCARDS,
    DEFAULT_PROBABILITY,
    TUBE_KINDS,
    Tube,
    certified_clearance,
    verdict,
)
from .linear import _linear_tube
from .sampled import linear_validity, sampled_tube


def predict_tube(law, noise, footprint: Footprint, world=None, *, rate_hz: float = 50.0, substeps: int = 4,
                 model=None, probability: float = DEFAULT_PROBABILITY, initial_cov: np.ndarray | None = None,
                 t_end: float | None = None, impulses: bool = True, kind: str = "auto",
                 confidence: float | None = None, discards: int = DEFAULT_DISCARDS, robot=None) -> Tube:
    """The error tube of ``law`` (a FeedbackLaw) under ``noise`` (a NoiseOptions), see the module
    docstring. ``world``: the CollisionWorld of the obstacles to certify against (None: no certified
    clearance). ``model``: the real robot (input limits for the saturation probability; default the
    nominal's, which for a plan with headroom is the derated one). ``initial_cov``: the initial error's
    covariance, diagonal (default: the noise's initial error; a replan starts from a measured state, whose
    error is the sensor noise). ``impulses``: include the noise's impulses (times from the start).

    ``kind``: "linear" (the linear-Gaussian tube), "sampled" (rollouts of the run loop,
    :func:`nhstab.tubes.sampled_tube`, with ``confidence`` and ``discards``), or "auto" (default): the linear tube
    where it holds (:func:`nhstab.tubes.linear_validity`: no input saturation to speak of and no
    interior stop), the sampled one elsewhere; the tube's ``certificate`` says which and why. With a
    world the tube carries its :func:`verdict` (without the plan's margin; call it again with it).

    ``robot``: a :class:`nhstab.robot.Robot`; one of several bodies (a car and its trailers) is certified
    body by body on rollouts (the linear tube covers the car's body only): with a world, "auto" takes
    the sampled tube, and a "linear" tube is returned without a certified clearance."""
    check_probability("probability", probability)
    if kind not in TUBE_KINDS:
        raise InputError("tube", "one of " + ", ".join(TUBE_KINDS), kind)
    confidence = DEFAULT_CONFIDENCE if confidence is None else confidence
    nominal_model = law.nominal.model
    model = model or nominal_model
    names = model.state_names
    lin, why = None, "asked for"
    multi = robot is not None and len(robot.footprints) > 1
    if multi and world is not None and kind == "auto":
        kind, why = "sampled", "a robot of several bodies: every body measured on rollouts of the run loop"
    if multi and kind == "linear":
        world = None                        # the linear tube's reach is the car's: no certificate for the rig
    if kind != "sampled":
        try:
            lin = _linear_tube(law, noise, footprint, None, rate_hz, substeps, model, probability, initial_cov,
                               t_end, impulses)
        except NumericalError:
            if kind == "linear":
                raise
            why = "the linearised closed loop diverges"
        if lin is not None:
            valid, why = linear_validity(lin, law.nominal)
            lin.certificate = {"kind": "linear", "probability": float(probability), "valid": valid, "why": why,
                               "statement": f"per control sample, probability >= {probability:g} under the closed loop "
                                            "linearised along the nominal (Gaussian noise, no input saturation)"}
            if kind == "linear" or valid:
                if world is not None:
                    (lin.certified_clearance, lin.certified_index, lin.nominal_clearance_there,
                     lin.clearance_evaluations) = certified_clearance(world, footprint, lin.poses, lin.reach)
                    verdict(lin, world, footprint)
                return lin
    sample_noise = noise
    if initial_cov is not None:
        S0 = np.asarray(initial_cov, dtype=float)
        if S0.shape != (model.n, model.n) or np.any(S0 != np.diag(np.diag(S0))) or np.any(np.diag(S0) < 0):
            raise InputError("initial_cov", "a diagonal covariance of the robot's states (the sampled tube draws "
                             "independent initial errors)", S0.shape)
        scale = float(noise.scale)
        raw = np.sqrt(np.diag(S0)) / scale if scale > 0 else np.zeros(model.n)
        sample_noise = replace(noise, distribution="gaussian", initial={s: float(v) for s, v in zip(names, raw)})
    if not impulses:
        sample_noise = replace(sample_noise, impulses=())
    tube = sampled_tube(law, sample_noise, footprint, world, rate_hz=rate_hz, substeps=substeps, model=model,
                        probability=probability, confidence=confidence, t_end=t_end, why=why, discards=discards,
                        robot=robot if multi else None)
    if world is not None:
        verdict(tube, world, footprint)
    return tube
