"""Calibration layer: campaigns, model files, the fitting engine, effects, diagnosis and
simulation."""
