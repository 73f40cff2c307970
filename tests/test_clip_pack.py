"""lab/gpu/clip_pack.py: a clip folder packed as qpos alone comes back as the same clips, qvel and obs derived again."""
import subprocess
import sys
from pathlib import Path

import numpy as np

from motions.clip import load_clip, save_clip
from motions.synthetic import arm_raise, squat

ROOT = Path(__file__).resolve().parents[1]


def clip_pack(*args: object) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "lab/gpu/clip_pack.py", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)


def test_packed_clips_unpack_to_the_same_motion_in_a_fraction_of_the_bytes(tmp_path):
    src, out = tmp_path / "clips", tmp_path / "back"
    for clip, stem in ((arm_raise(2.0), "first"), (squat(3.0), "second")):
        save_clip(clip, src / f"{stem}.npz")
    pack = tmp_path / "clips.pack.npz"
    done = clip_pack("pack", src, pack)
    assert done.returncode == 0, done.stderr
    assert pack.stat().st_size < sum(f.stat().st_size for f in src.glob("*.npz")) / 2
    assert clip_pack("unpack", pack, out).returncode == 0
    assert sorted(f.name for f in out.glob("*.npz")) == ["first.npz", "second.npz"]
    for stem in ("first", "second"):
        a, b = load_clip(src / f"{stem}.npz"), load_clip(out / f"{stem}.npz")
        assert (a.name, a.source, a.license, a.n_frames) == (b.name, b.source, b.license, b.n_frames)
        np.testing.assert_allclose(b.qpos, a.qpos, atol=1e-6)
        np.testing.assert_allclose(b.qvel, a.qvel, atol=1e-3)
        np.testing.assert_allclose(b.obs, a.obs, atol=1e-3)


def test_a_file_that_is_no_pack_is_refused_by_name(tmp_path):
    other = tmp_path / "other.npz"
    np.savez(other, qpos=np.zeros((3, 76)))
    done = clip_pack("unpack", other, tmp_path / "back")
    assert done.returncode != 0 and "other.npz: not a clip pack" in done.stderr
    assert not (tmp_path / "back").exists()
