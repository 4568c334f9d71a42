"""nhstab: plan, stabilize and stress-test nonholonomic robots.

The library follows the pipeline of the composite controller of Walsh, Tilbury, Sastry, Murray and
Laumond (1992): robot models (``pipeline.models``), nominal trajectories (``pipeline.nominal``),
the gramian gain schedule (``pipeline.control``) and the closed loop (``pipeline.simulation``).
"""

__version__ = "0.1.0"
