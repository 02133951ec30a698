"""Elastic layer: the robot with its joint laws, link bends, target shifts and measurement
effects (the effect library), its model file, and the loaded robot's exact equilibrium."""
