"""SE(2) helpers: angle wrapping. (Footprints arrive with the maps issue.)"""

from __future__ import annotations

import numpy as np


def wrap_angle(angle):
    """Wrap angles to [-pi, pi). Works elementwise on arrays."""
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi
