"""Machining layer: deflection compensation along a path and the stiffest posture about the
tool axis."""
