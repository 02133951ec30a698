"""Mechanics layer: K_C, compliance, K_X in both formulations and connections, definiteness, work
balance, the exact equilibrium."""
