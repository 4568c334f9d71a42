"""nhstab: plan, stabilize and stress-test nonholonomic robots.

The library follows the composite controller of Walsh, Tilbury, Sastry, Murray and Laumond (1992):
a map and a robot go in, a collision-free nominal trajectory is planned, the gramian feedback law
stabilizes the robot to it under noise, FCL monitors the clearance and the robot replans when it
senses what the map missed.

The names a user needs for the common jobs are here, at the top (each is documented where it lives):

======================== ==========================================================================
``load_map(path)``       any supported map file, or ``"example:NAME"`` (a bundled one) -> ``Map``
``list_examples()``      the bundled maps and scenarios (``nhstab examples``)
``make_robot(model)``    a robot: model, parameters, footprint, margin, stabilizer defaults (``Robot``)
``load_robot(path)``     a robot described in YAML (``--robot-config``); ``default_robot(name)``
``make_model(name)``     a bare model by name (``unicycle``, ``rwd_car``, ``fwd_car``, ``heisenberg``)
``default_footprint``    the footprint of a model's built-in robot
``plan(m, robot, s, g)`` map + robot + start/goal -> ``PlanResult`` with a feasible ``Nominal``
``PathOptions``          options of the planning search (planner, budget, seed, margin)
``TimingOptions``        the nominal's time parameterisation (speed and acceleration limits)
``CollisionWorld``       the FCL world of a map's obstacles (``CollisionWorld.from_map(m, "known")``)
``compute_schedule``     the gramian gain schedule along a nominal (``StabilizerOptions``)
``predict_tube(...)``    the error tube of a feedback law under a noise model (``nhstab.tubes``): linear where
                         it holds, else ``sampled_tube`` (rollouts of the run loop, ``nhstab.tubes.sampled``)
``tube_line(tube)``      the one line that says whether a tube is certified, where and what would certify it
``build_law``            the feedback law (gramian, TVLQR, open loop) along a plan's nominal, for a tube
``NoiseOptions``         the noise model of a run (initial error, sensor and process noise, impulses)
``execute(m, robot)``    one run of the composite controller -> ``RunResult``
``RunOptions``           options of a run (controller, noise, sensing, replanning); ``load_run_config``
``write_run``            a run's files (run.json, trajectory.csv, figures)
``load_batch_config``    a Monte Carlo batch config; ``run_batch`` runs it into a store -> ``BatchSummary``
======================== ==========================================================================

Submodules: ``nhstab.models``, ``nhstab.maps``, ``nhstab.collision``, ``nhstab.planning``,
``nhstab.control``, ``nhstab.execution``, ``nhstab.batch``, ``nhstab.report``.

The names are imported on first use, so ``import nhstab`` stays cheap.
"""

from __future__ import annotations

from importlib import import_module

from ._version import __version__

#: public name -> module that defines it
_PUBLIC = {
    "load_map": "nhstab.maps",
    "Map": "nhstab.maps",
    "list_examples": "nhstab.examples",
    "make_model": "nhstab.models",
    "make_robot": "nhstab.robot",
    "load_robot": "nhstab.robot",
    "default_robot": "nhstab.robot",
    "Robot": "nhstab.robot",
    "default_footprint": "nhstab.robot",
    "plan": "nhstab.planning",
    "PathOptions": "nhstab.planning",
    "TimingOptions": "nhstab.planning",
    "CollisionWorld": "nhstab.collision",
    "PlanResult": "nhstab.planning",
    "Nominal": "nhstab.nominal",
    "compute_schedule": "nhstab.control",
    "StabilizerOptions": "nhstab.control",
    "predict_tube": "nhstab.tubes",
    "sampled_tube": "nhstab.tubes",
    "tube_line": "nhstab.tubes",
    "execute": "nhstab.execution",
    "build_law": "nhstab.execution",
    "NoiseOptions": "nhstab.execution.config",
    "RunOptions": "nhstab.execution",
    "RunResult": "nhstab.execution",
    "load_run_config": "nhstab.execution",
    "write_run": "nhstab.execution",
    "load_batch_config": "nhstab.batch.config",
    "run_batch": "nhstab.batch.runner",
    "BatchSummary": "nhstab.batch.runner",
    "PipelineError": "nhstab.errors",
    "InputError": "nhstab.errors",
}

__all__ = ["__version__", *_PUBLIC]


def __getattr__(name: str):
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'nhstab' has no attribute {name!r}")
    value = getattr(import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_PUBLIC))
