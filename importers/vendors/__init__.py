"""Readers for the files other insoles' software writes, picked by the file's own header.

``read_vendor(path)`` detects the format (importers/vendors/detect.py) and
reads the file whole, line by line, into one ``VendorRecording``: times on
the file's clock, the feet it holds (a grid or discrete cells each, in the
file's units, with the factor to kPa), events, tags and the rest of its
header. One module per format; importers/IMPORT.md, "Vendor files", has the
table.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Final

from scotti.importers.errors import InputError
from scotti.importers.vendors.detect import FORMATS, VENDOR_FORMATS, detect
from scotti.importers.vendors.fscan import read_fscan
from scotti.importers.vendors.gaitpdb import read_gaitpdb
from scotti.importers.vendors.moticon import read_moticon
from scotti.importers.vendors.pedar import read_pedar
from scotti.importers.vendors.recording import FootData, VendorRecording
from scotti.importers.vendors.xsensor import read_xsensor

READERS: Final[dict[str, Callable[[Path], VendorRecording]]] = {
    "pedar": read_pedar,
    "fscan": read_fscan,
    "xsensor": read_xsensor,
    "moticon": read_moticon,
    "gaitpdb": read_gaitpdb,
}


def read_vendor(
    path: str | Path, format: str | None = None, *, foot: str | None = None
) -> VendorRecording:
    """Read a vendor export; ``format`` (one of ``VENDOR_FORMATS``) skips detection.

    ``foot``: which insole a one-insole file is, where the file cannot say
    (F-Scan; the others name their insoles).
    """
    p = Path(path)
    name = format or detect(p)
    if name not in READERS:
        raise InputError(p, f"{name!r} is not a vendor format ({', '.join(VENDOR_FORMATS)})")
    if not p.is_file():
        raise InputError(p, "no such file")
    if name == "fscan":
        return read_fscan(p, foot)
    return READERS[name](p)


__all__ = [
    "FORMATS",
    "VENDOR_FORMATS",
    "FootData",
    "VendorRecording",
    "detect",
    "read_vendor",
]
