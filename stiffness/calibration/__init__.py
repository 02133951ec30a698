"""Calibration layer: campaigns, the fitting engine, identification and diagnosis (with the
information a measurement adds, used by diagnose's proposals and by the design layer)."""
