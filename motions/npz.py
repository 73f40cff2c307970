"""Reading `.npz` archives (clips, AMASS files) without trusting them: headers first, data second, never pickle.

`np.load` inflates a member before anything can be checked, returns a bare array for a `.npy` renamed `.npz`, and
answers a random file with advice to unpickle it; this reader checks each member's declared shape and dtype
before reading a byte of its data.
"""
from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from motions.limits import MAX_ARRAY_BYTES, MAX_SECONDS_ENV, check_input_file, max_clip_seconds


def read_npz(path: Path, keys: tuple[str, ...], error: type[Exception], what: str,
             max_rows: int | None = None) -> dict[str, np.ndarray]:
    """The members of `keys` that the archive holds (missing ones are left out for the caller to name); raises
    `error` naming the file for anything that is not a plain-array .npz of sane size. `what` names the expected
    kind of file ("clip archive", "AMASS .npz") in messages; `max_rows` bounds every array's frame count."""
    check_input_file(path, error)
    try:  # opened here: zipfile.is_zipfile reads an unreadable file as "not a zip" and hides why
        with open(path, "rb") as fh:
            is_zip = zipfile.is_zipfile(fh)
    except OSError as err:
        raise error(f"{path}: cannot be read ({err.strerror or err})") from None
    if not is_zip:
        raise error(f"{path}: not a valid {what} (not a zip archive)")
    out: dict[str, np.ndarray] = {}
    try:
        with zipfile.ZipFile(path) as zf:
            members = set(zf.namelist())
            for key in keys:
                if f"{key}.npy" not in members:
                    continue
                with zf.open(f"{key}.npy") as fh:
                    shape, dtype = _header(fh, path, key, error, what)
                    if max_rows is not None and shape and shape[0] > max_rows:
                        raise error(f"{path}: member {key!r} declares {shape[0]} frames, over the limit of "
                                    f"{max_rows} ({max_clip_seconds():.4g} s; set {MAX_SECONDS_ENV} to allow "
                                    "longer clips)")
                    nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
                    if nbytes > MAX_ARRAY_BYTES:
                        raise error(f"{path}: member {key!r} declares shape {shape} ({nbytes / 2**30:.3g} GiB), "
                                    f"over the {MAX_ARRAY_BYTES / 2**30:g} GiB limit on one array")
                with zf.open(f"{key}.npy") as fh:
                    out[key] = np.lib.format.read_array(fh, allow_pickle=False)
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, NotImplementedError) as err:
        if isinstance(err, error):
            raise
        raise error(f"{path}: not a valid {what} ({err})") from None
    except MemoryError:
        raise error(f"{path}: too large to load into memory") from None
    return out


def _header(fh, path: Path, key: str, error: type[Exception], what: str) -> tuple[tuple[int, ...], np.dtype]:
    version = np.lib.format.read_magic(fh)
    if version == (1, 0):
        shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
    elif version == (2, 0):
        shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
    else:
        raise error(f"{path}: member {key!r} has unsupported .npy version {version}")
    if dtype.hasobject:
        raise error(f"{path}: member {key!r} holds Python objects, which are never unpickled: not a valid {what}")
    return shape, dtype
