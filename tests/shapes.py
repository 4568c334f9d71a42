"""Shared test helper: a map's obstacles as shapely geometry, independent of nhstab's collision code."""

import shapely.geometry as sg


def shapely_obstacles(m):
    """Every obstacle of map ``m`` (polygons; circles as 256-gon buffers) and the outside of its bounds (a 1 m
    frame), as one shapely GeometryCollection."""
    shapes = [sg.Polygon(o.vertices) if hasattr(o, "vertices") else sg.Point(*o.center).buffer(o.radius, 256)
              for o in m.obstacles]
    xmin, ymin, xmax, ymax = m.bounds
    shapes.append(sg.box(xmin - 1, ymin - 1, xmax + 1, ymax + 1).difference(sg.box(xmin, ymin, xmax, ymax)))
    return sg.GeometryCollection(shapes)
