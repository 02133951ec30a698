"""Papers layer: the reproduction of Alici & Shirinzadeh (2005) on the Motoman SK120, using the
toolkit as a user would."""
