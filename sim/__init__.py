"""Scene simulator: subjects, motions, plantar pressure, effects, session files."""


class SimError(Exception):
    """Root of the simulator's errors: a user's mistake, one line, no traceback."""
