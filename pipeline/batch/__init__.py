"""Batch robustness studies: many trials of the composite controller (see :mod:`nhstab.batch.vector` for
the vectorised engine for trials that share one nominal)."""
