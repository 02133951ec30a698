"""Unit names of user files and flags, and their factors to SI (rad, N, m, N.m)."""

import math

#: Unit name -> factor to SI (rad, N, m).
ANGLE_UNITS = {"deg": math.pi / 180.0, "rad": 1.0}
FORCE_UNITS = {"N": 1.0, "kN": 1e3}
LENGTH_UNITS = {"mm": 1e-3, "m": 1.0, "cm": 1e-2, "um": 1e-6}
#: Moment unit name -> factor to N.m (every force unit times every length unit).
MOMENT_UNITS = {f"{f}.{ln}": FORCE_UNITS[f] * LENGTH_UNITS[ln]
                for f in FORCE_UNITS for ln in LENGTH_UNITS}
