"""Error tubes: how far the stabilized robot strays from its nominal, and the clearance that leaves.

For a nominal and its feedback law, the run's control rate, the plant's substeps and the noise model,
:func:`predict_tube` gives a :class:`Tube`: per control sample, the reach of the footprint's
displacement at probability p, and the certified clearance (the smallest clearance of the footprint
grown by that reach, measured with FCL).

- :mod:`nhstab.tubes.covariance`: mean and covariance of the tracking error of the closed loop
  linearised along the nominal, and the probability that an input saturates;
- :mod:`nhstab.tubes.linear`: the linear-Gaussian tube built from them (per sample, probability >= p);
- :mod:`nhstab.tubes.sampled`: the sampled tube, N rollouts of the run loop itself with a
  finite-sample certificate for the whole run, where the linear model does not hold (saturation,
  stops, cusps);
- :mod:`nhstab.tubes.predict`: the choice between them (``kind="auto"``);
- :mod:`nhstab.tubes.fit`: plans and gains that fit their tube (``--margin auto``, ``--fit``,
  ``--gains auto``);
- :mod:`nhstab.tubes.base`: the :class:`Tube` record, the run's sample schedule, the verdict and the
  one-line report.
"""

from __future__ import annotations

from .._lazy import lazy_exports

#: public name -> the module that defines it
_NAMES = {
    "CONSTRUCTION": ".base",
    "DEFAULT_PROBABILITY": ".base",
    "SAMPLED_CONSTRUCTION": ".base",
    "SampleSchedule": ".base",
    "Tube": ".base",
    "certified_clearance": ".base",
    "certified_text": ".base",
    "displacement": ".base",
    "failing_samples": ".base",
    "hull_vertices": ".base",
    "initial_covariance": ".base",
    "pose_indices": ".base",
    "run_schedule": ".base",
    "tube_line": ".base",
    "tube_needs": ".base",
    "verdict": ".base",
    "AUTO_GAINS_ALPHA": ".fit",
    "AUTO_GAINS_DELTA": ".fit",
    "AUTO_GAINS_GAMMA": ".fit",
    "AUTO_GAINS_MAX_SATURATION": ".fit",
    "AUTO_MARGIN_ROUNDS": ".fit",
    "AUTO_MARGIN_SLACK": ".fit",
    "AUTO_MARGIN_START": ".fit",
    "FIT_TRIES": ".fit",
    "SEVERAL_BODIES": ".fit",
    "choose_gains": ".fit",
    "fit_plan": ".fit",
    "plan_and_tube": ".fit",
    "plan_with_auto_margin": ".fit",
    "predict_tube": ".predict",
    "DEFAULT_CONFIDENCE": ".sampled",
    "LINEAR_MAX_SATURATION": ".sampled",
    "ROLLOUT_SEED_BASE": ".sampled",
    "TUBE_KINDS": ".sampled",
    "cusp_stops": ".sampled",
    "interior_stops": ".sampled",
    "linear_validity": ".sampled",
    "remaining_law": ".sampled",
    "rollout_clearance": ".sampled",
    "rollouts_needed": ".sampled",
    "sampled_tube": ".sampled",
}

__getattr__, __dir__, __all__ = lazy_exports(__name__, _NAMES)
