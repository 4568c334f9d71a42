"""Parking scenes built from their geometry, for the car planner's tests (not the official suite).

Each builder returns (map, start, goal) for a car described by its footprint (a rectangle: length,
width, rear overhang) and its turning radius. World frame: x along the kerb or aisle, y across.
"""

from __future__ import annotations

import math

import numpy as np
from nhstab.maps.base import Map, box_polygon


def car_dims(robot) -> dict:
    """Length, width, rear overhang b, front overhang f and wheelbase L of a rectangular car footprint."""
    v = robot.footprint.vertices
    b, front = -float(v[:, 0].min()), float(v[:, 0].max())
    L = float(robot.model.wheelbase)
    return {"length": b + front, "width": float(v[:, 1].max() - v[:, 1].min()), "b": b, "f": front - L, "L": L}


def single_maneuver_length(robot, radius: float | None = None) -> float:
    """L1 = b + sqrt((R + w/2)^2 + (L + f)^2 - (R - w/2)^2), R the rear axle's minimum turning radius."""
    d = car_dims(robot)
    R = robot.min_turning_radius if radius is None else radius
    w = d["width"]
    return d["b"] + math.sqrt((R + w / 2) ** 2 + (d["L"] + d["f"]) ** 2 - (R - w / 2) ** 2)


def parallel_slot(robot, factor: float, kerb_gap: float = 0.2, lane: float = 6.0, start_behind: bool = True):
    """A slot factor x L1 long between two parked boxes (the car's size) at ``kerb_gap`` from a kerb
    (y < 0); the lane above them is ``lane`` metres wide. The goal: the car centred in the slot at the
    parked cars' lateral position, heading +x; the start: in the lane, behind the slot."""
    d = car_dims(robot)
    slot = factor * single_maneuver_length(robot)
    x_rear = 10.0                                     # the rear parked car's front end
    y_mid = kerb_gap + d["width"] / 2
    top = kerb_gap + d["width"] + lane
    obstacles = (
        box_polygon(x_rear - d["length"] / 2, y_mid, d["length"], d["width"]),
        box_polygon(x_rear + slot + d["length"] / 2, y_mid, d["length"], d["width"]),
        box_polygon(15.0, -0.5, 40.0, 1.0),          # kerb
    )
    m = Map(f"parallel {factor:g} L1", (-5.0, -1.0, 35.0, top), obstacles=obstacles)
    goal = np.array([x_rear + (slot - d["length"]) / 2 + d["b"], y_mid, 0.0])
    start = np.array([x_rear - d["length"] - 1.0 if start_behind else x_rear + slot + 6.0,
                      kerb_gap + d["width"] + lane / 2, 0.0])
    return m, start, goal


def bay(robot, aisle: float, angle_deg: float = 90.0, bay_width: float = 2.5, reverse_in: bool = True,
        neighbours: int = 2):
    """A row of bays at ``angle_deg`` to an aisle ``aisle`` metres wide (the car's length deep, plus 0.8 m);
    parked boxes fill ``neighbours`` bays each side of the free one; a wall (or a row of parked cars)
    closes the aisle's far side. Goal: the car in the free bay, nose to the aisle if ``reverse_in``;
    start: in the aisle, well to the left, heading +x."""
    d = car_dims(robot)
    depth = d["length"] + 0.8
    a = math.radians(angle_deg)
    ux, uy = math.cos(a), -math.sin(a)                 # the bay axis, pointing away from the aisle (down)
    pitch = bay_width / math.sin(a)                    # bay spacing along the aisle
    x0 = 15.0
    shapes = []
    for k in range(-neighbours, neighbours + 1):
        if k == 0:
            continue
        cx = x0 + k * pitch + ux * depth / 2
        cy = uy * depth / 2
        shapes.append(box_polygon(cx, cy, d["length"], d["width"], yaw=math.atan2(uy, ux)))
    # the back of the bays, and the aisle's far side
    y_back = -(depth * math.sin(a) + bay_width / 2 * abs(math.cos(a))) - 0.3    # below every bay's corner
    shapes.append(box_polygon(15.0, y_back - 0.5, 40.0, 1.0))
    shapes.append(box_polygon(15.0, aisle + 0.5, 40.0, 1.0))
    m = Map(f"bay {angle_deg:g} deg aisle {aisle:g}", (-5.0, y_back - 1.0, 35.0, aisle + 1.0), obstacles=tuple(shapes))
    # the goal: the car's centre at the bay's centre, axis along the bay
    centre = np.array([x0 + ux * depth / 2, uy * depth / 2])
    heading = math.atan2(-uy, -ux) if reverse_in else math.atan2(uy, ux)
    mid_from_axle = d["length"] / 2 - d["b"]
    goal = np.array([centre[0] - mid_from_axle * math.cos(heading), centre[1] - mid_from_axle * math.sin(heading),
                     heading])
    start = np.array([2.0, aisle / 2, 0.0])
    return m, start, goal
