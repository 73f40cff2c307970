"""Motion clips for the SMPL humanoid: format, importers, retargeting and the motion library.

Public API: `Clip`, `load_clip`, `save_clip` (motions.clip), `MotionLibrary` (motions.library),
`import_file` (motions.importers), `default_library` / `default_clips` (motions.synthetic). See docs/motions.md.
"""
from motions.clip import Clip, ClipFormatError, load_clip, save_clip
from motions.library import MotionLibrary

__all__ = ["Clip", "ClipFormatError", "MotionLibrary", "load_clip", "save_clip"]
