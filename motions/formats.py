"""Which motion format a file holds, from its first bytes: the one piece of the importers that reading a clip needs
(to point at `fbcpr motions import` when a clip path is really a motion file)."""
from __future__ import annotations

import os
from pathlib import Path

from motions.limits import check_input_file

FORMATS = ("amass", "deepmimic", "bvh", "amc")


class UnknownFormatError(ValueError):
    """The file is none of the supported motion formats."""


def detect_format(path: str | os.PathLike) -> str:
    """'amass', 'deepmimic', 'bvh' or 'amc' (an Acclaim motion, read on its ASF skeleton), judged from the file's
    first bytes (not its name). An ASF skeleton alone is no motion: UnknownFormatError says to import its AMCs."""
    path = Path(path)
    check_input_file(path, UnknownFormatError)
    try:
        with open(path, "rb") as fh:
            head = fh.read(512)
    except OSError as err:
        raise UnknownFormatError(f"{path}: cannot read ({err.strerror})") from None
    if head.startswith(b"PK"):
        return "amass"
    text = head.lstrip(b"\xef\xbb\xbf").lstrip()
    if text.startswith(b"HIERARCHY"):
        return "bvh"
    if text.startswith(b"{"):
        return "deepmimic"
    if b":FULLY-SPECIFIED" in head or b":DEGREES" in head:
        return "amc"
    if b":bonedata" in head or b":version" in head:
        raise UnknownFormatError(f"{path}: an ASF skeleton, not a motion: import its .amc motions (the skeleton is "
                                 "found beside them, or named with --skeleton)")
    raise UnknownFormatError(f"{path}: not a supported motion file (expected AMASS .npz, DeepMimic JSON, BVH or "
                             "ASF/AMC)")
