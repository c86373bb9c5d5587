"""Bounds of the command line and of scenario files that must be known before anything heavy is
imported (the ``nrtraffic`` command checks its flags with them first)."""

MAX_DURATION_S = 7 * 24 * 3600.0  # longest simulated time accepted [s] (a week)
MAX_SEED = 2**31 - 1  # SUMO's --seed is a signed 32-bit integer
