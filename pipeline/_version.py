"""The version of nhstab, in one place (pyproject.toml reads it; ``nhstab --version`` prints it)."""

__version__ = "0.2.0"
