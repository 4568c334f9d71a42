"""The sampled tube of a robot of several bodies (a car and its trailer): every body displaced and measured,
the certificate against every rollout pose of every body measured directly, and jackknifes counted."""

from __future__ import annotations

import numpy as np
import pytest
from nhstab.collision import CollisionWorld
from nhstab.execution import ControllerOptions, build_law
from nhstab.execution.config import NoiseOptions
from nhstab.maps.base import Map, box_polygon
from nhstab.nominal import Nominal
from nhstab.robot import default_robot
from nhstab.tubes.base import displacement, hull_vertices
from nhstab.tubes.predict import predict_tube
from nhstab.tubes.sampled import sampled_tube

DISCARDS = 2
ROLLOUTS = 40


def _straight(direction: float):
    """The default rig driving straight at 1 m/s for 16 s (forward from x = 4 or in reverse from x = 20, its
    trailer in line), beside a wall whose lower edge is 1.35 m above the rig's side."""
    robot = default_robot("car_trailer")
    model = robot.model
    t = np.arange(0.0, 16.0 + 1e-9, 0.02)
    x0 = 20.0 if direction < 0 else 4.0
    X = np.column_stack([x0 + direction * t, 0 * t + 3.0, 0 * t, 0 * t, 0 * t])
    nom = Nominal.from_samples(model, t, X, np.column_stack([direction + 0 * t, 0 * t]))
    law = build_law(nom, ControllerOptions(kind="gramian"), robot.stabilizer.as_dict())
    m = Map("wall", (-8.0, -2.0, 30.0, 8.0), obstacles=(box_polygon(12.0, 5.4, 24.0, 0.3),))
    return robot, law, CollisionWorld.from_map(m, "known")


@pytest.mark.parametrize("direction,scale", [(1.0, 1.0), (1.0, 3.0), (-1.0, 1.0)])
def test_every_body_is_measured_and_jackknifes_are_counted(direction, scale):
    """Certified clearance = the 3rd smallest over the rollouts of their smallest FCL clearance over every
    body and sample (measured here pose by pose, body by body); each body's reach the 3rd largest of its
    displacements at each sample, the tube's the largest of them; the jackknifes those of the rollouts'
    hitch angles beyond the model's limit, and a tube with more of them than discarded rollouts is not
    certified. Forward at the default noise and three times it, and in reverse, where the trailer
    jackknifes in some rollouts."""
    robot, law, world = _straight(direction)
    model = robot.model
    tube = sampled_tube(law, NoiseOptions(scale=scale), robot.footprint, world, model=model, rollouts=ROLLOUTS,
                        keep_states=True, discards=DISCARDS, robot=robot)
    X = tube.info["states"]                                   # (N, S, n)
    bp = robot.body_poses(X)                                  # (N, S, B, 3)
    nominal = robot.body_poses(law.nominal.x[:X.shape[1]])    # the tube's samples are the nominal's grid
    c = np.stack([world.clearance_many(bp[:, :, b].reshape(-1, 3), fp).reshape(X.shape[:2])
                  for b, fp in enumerate(robot.footprints)])  # (B, N, S)
    g = c.min(axis=(0, 2))
    rc = tube.info["rollout_clearance"]
    if rc["exact"]:
        assert tube.certified_clearance == pytest.approx(np.sort(g)[DISCARDS], abs=1e-12)
        i = rc["rollout"]
        assert g[i] == pytest.approx(np.sort(g)[DISCARDS], abs=1e-12)
        assert c[rc["body"], i, rc["sample"]] == pytest.approx(g[i], abs=1e-12)
    else:                          # a deep contact: the search stops early, at or above the exact value
        assert tube.certified_clearance >= np.sort(g)[DISCARDS] - 1e-12 and tube.certified_clearance < 0
    per_body = []
    for b, fp in enumerate(robot.footprints):
        D = displacement(hull_vertices(fp), bp[:, :, b], nominal[None, :, b])     # (N, S)
        per_body.append(np.sort(D, axis=0)[-1 - DISCARDS])
    assert np.allclose(tube.info["body_reach"], per_body, atol=1e-9)
    assert np.allclose(tube.reach, np.max(per_body, axis=0), atol=1e-9)
    jack = int((np.abs(model.hitch_angles(X)) > model.jackknife_limit).any(axis=(1, 2)).sum())
    assert tube.certificate["jackknifes"] == jack and tube.certificate["bodies"] == 2
    assert tube.certified == (tube.certified_clearance >= 0 and jack <= DISCARDS)
    if direction < 0:
        assert jack > DISCARDS and tube.certified is False


def test_predict_tube_certifies_a_rig_on_rollouts_and_not_linearly():
    """With a world, a rig's auto tube is the sampled one (the linear tube's reach is the car's); a linear
    tube asked for is returned without a certified clearance; without the robot, the car alone is measured."""
    robot, law, world = _straight(1.0)
    noise = NoiseOptions()
    auto = predict_tube(law, noise, robot.footprint, world, model=robot.model, robot=robot)
    assert auto.kind == "sampled" and auto.certificate["bodies"] == 2
    assert "several bodies" in auto.certificate["why"]
    lin = predict_tube(law, noise, robot.footprint, world, model=robot.model, robot=robot, kind="linear")
    assert lin.kind == "linear" and lin.certified_clearance is None and lin.certified is None
