"""Figures and tables. Functions return matplotlib figures and never show them."""

import matplotlib

matplotlib.use("Agg")
