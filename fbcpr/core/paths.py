"""Where a command may write: one check for every command that writes a folder (`fbcpr export OUT`, `fbcpr train
--out`, `fbcpr npmp distill --out`, `fbcpr motions import --out`), run before anything is written.

An output folder may not be one of the command's inputs, lie inside one, or contain one: writing it would replace
or mix with what the command reads (an export over its own training checkpoint deletes the trainer state and the
replay buffer). Nor may it be an existing file, which a folder would replace. Paths are compared after following
symbolic links, so a link to the source is the source.
"""
from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from fbcpr.core.errors import InputError


def real(path: str | Path) -> Path:
    """`path` made absolute with every symbolic link followed as far as it exists (a loop is left as it is)."""
    return Path(os.path.realpath(os.path.expanduser(str(path))))


def check_output_folder(out: str | Path, arg: str, sources: Iterable[tuple[str, str | Path]] = ()) -> None:
    """InputError naming `arg` (e.g. "--out") unless the folder `out` may be written: it is not an existing file
    (or anything else but a folder), and neither it nor a folder inside it is one of `sources` ((argument, path)
    pairs: the inputs of the command), nor does it lie inside one."""
    out_path = Path(out).expanduser()
    if os.path.lexists(out_path) and not out_path.is_dir():
        kind = "a symbolic link that leads nowhere" if not out_path.exists() else "an existing file"
        raise InputError(f"{arg}: {out} is {kind}, not a folder; it would be replaced by one (choose another path)")
    target = real(out_path)
    for name, src in sources:
        source = real(src)
        if target == source:
            how = "is"
        elif source in target.parents:
            how = "lies inside"
        elif target in source.parents:
            how = "contains"
        else:
            continue
        raise InputError(f"{arg}: {out} {how} {name} {src}; writing it would overwrite or mix with what is read "
                         f"from there (choose a folder apart from it)")


def check_output_file(out: str | Path, arg: str) -> None:
    """InputError naming `arg` (e.g. "--save-z") unless the file `out` can be created: its folder exists and it is
    not itself a folder. Checked before the work, so a long command does not fail at its last write."""
    out_path = Path(out).expanduser()
    folder = out_path.parent
    if out_path.is_dir():
        raise InputError(f"{arg}: {out} is a folder; give a file path in it")
    if not folder.is_dir():
        why = "is not a folder" if os.path.lexists(folder) else "does not exist"
        raise InputError(f"{arg}: {out}: the folder {folder} {why} (create it first, or choose another path)")
