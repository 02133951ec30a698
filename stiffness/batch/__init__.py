"""Batch layer: vectorised elastostatics over arrays of configurations and loads."""
