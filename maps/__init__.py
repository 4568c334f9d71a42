"""The maps and scenarios bundled with nhstab (installed as the package data ``nhstab.data``).

See :mod:`nhstab.examples` and ``nhstab examples``; each folder has a SOURCE.md with its origin and
licence."""
