"""Plots (matplotlib, Agg backend, imported lazily inside the plotting functions)."""
