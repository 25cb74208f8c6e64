"""Importers: other insoles' and motion-capture recordings into session files.

``scotti import`` reads pressure (CSV, ``.npz``, HDF5), keypoints (the same
containers, in a named set or a user's mapping) and action labels, puts them
on the model contract (32 x 22 grid, count scale, 16 Hz, pose frame,
progress from the paper's indicators) and writes a session file with source
``imported``: packets as a board would send them, and label records. So
``scotti train``, ``scotti eval``, replay and ``scotti session info`` take
it as they take a recorded or simulated one. The mapping, with pictures:
importers/IMPORT.md.

May import firmware_protocol, models and numpy (h5py lazily, the
``[import]`` extra); never torch, never the daemon.
"""

from __future__ import annotations

from scotti.importers.errors import ImporterError, InputError

__all__ = ["ImporterError", "InputError"]
