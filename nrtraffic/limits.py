"""Bounds of the command line and of scenario files that must be known before anything heavy is
imported (the ``nrtraffic`` command checks its flags with them first)."""

MAX_DURATION_S = 7 * 24 * 3600.0  # longest simulated time accepted [s] (a week)
MAX_SEED = 2**31 - 1  # SUMO's --seed is a signed 32-bit integer
# characters SUMO does not take in a vehicle id (SUMOXMLDefinitions::isValidVehicleID)
SUMO_ID_FORBIDDEN = " \t\n\r|\\'\";,<>&"


def sumo_id_problem(vid: str) -> str | None:
    """Why SUMO would refuse ``vid`` as a vehicle id (None: it takes it)."""
    if not vid:
        return "it is empty"
    bad = sorted({c for c in vid if c in SUMO_ID_FORBIDDEN or ord(c) < 32 or ord(c) == 127})
    if bad:
        return "SUMO takes no " + " or ".join(repr(c) for c in bad) + " in a vehicle id"
    return None


def sumo_time(text: str) -> float:
    """A time as SUMO reads one [s]: seconds, or ``[[[D:]H:]M:]S`` (``07:00:30``). Raises
    ValueError where it is neither."""
    parts = str(text).strip().split(":")
    if len(parts) > 4:
        raise ValueError(text)
    return sum(float(x) * f for x, f in zip(reversed(parts), (1.0, 60.0, 3600.0, 86400.0)))
