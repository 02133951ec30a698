"""Robot layer: loading robots (URDF, example-robot-data, shipped), loop declarations and
closure, and every Pinocchio quirk."""
