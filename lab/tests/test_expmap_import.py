"""lab/experiments/expmap_import.py: the exponential-map CMU set through the package's retargeter, checked against
the same capture imported from CMU's own ASF/AMC files."""
import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from motions.clip import load_clip
from motions.importers import import_file
from motions.retarget import Retargeter

SCRIPT = Path(__file__).parents[1] / "experiments" / "expmap_import.py"
spec = importlib.util.spec_from_file_location("expmap_import", SCRIPT)
expmap_import = importlib.util.module_from_spec(spec)
spec.loader.exec_module(expmap_import)

CMU = Path(__file__).parents[2].parent / "shared" / "mocap" / "cmu"
WALK = CMU / "expmap" / "train" / "walking" / "walking_1.txt"  # subject 02's take 01, as 02_01.amc
needs_cmu = pytest.mark.skipif(not WALK.is_file(), reason=f"the exponential-map set not found in {CMU}")


def test_the_rest_skeleton_stands_upright_with_left_on_the_left():
    rest = np.zeros((1, 3 + 3 * expmap_import.N_JOINTS))
    pos = expmap_import.forward_kinematics(rest)[0]
    kp = expmap_import.KEYPOINT_JOINTS
    assert pos[kp["head"], 1] > pos[kp["neck"], 1] > pos[kp["l_hip"], 1] > pos[kp["l_knee"], 1] > pos[kp["l_ankle"], 1]
    assert pos[kp["l_hip"], 0] > 0 > pos[kp["r_hip"], 0]  # CMU: y up, facing +z, so left is +x
    assert pos[kp["l_toe"], 2] > pos[kp["l_ankle"], 2]  # toes forward
    turned = rest.copy()
    turned[0, 3 + 3 * 3:3 + 3 * 4] = [np.pi / 2, 0, 0]  # the left knee's own joint bent a quarter turn
    bent = expmap_import.forward_kinematics(turned)[0]
    assert np.allclose(bent[: kp["l_ankle"]], pos[: kp["l_ankle"]])  # what is above it does not move
    assert np.linalg.norm(bent[kp["l_ankle"]] - bent[kp["l_knee"]]) == pytest.approx(
        np.linalg.norm(pos[kp["l_ankle"]] - pos[kp["l_knee"]]))
    assert not np.allclose(bent[kp["l_ankle"]], pos[kp["l_ankle"]])


@needs_cmu
def test_a_real_file_retargets_like_its_asf_amc_twin():
    src = expmap_import.load_expmap(WALK)
    qpos, report = Retargeter().run(src)
    twin, twin_report = import_file(CMU / "asfamc" / "02_01.amc", use_cache=False)
    n = min(len(qpos), len(twin.qpos))
    assert abs(len(qpos) - len(twin.qpos)) <= 1
    assert np.all(np.isfinite(qpos))
    moving = (qpos[:n, 7:].std(axis=0) > 0.05) & (twin.qpos[:n, 7:].std(axis=0) > 0.05)
    corr = [np.corrcoef(qpos[:n, 7 + j], twin.qpos[:n, 7 + j])[0, 1] for j in np.flatnonzero(moving)]
    assert len(corr) > 15 and np.median(corr) > 0.95  # the same joint angles
    travel = qpos[-1, :2] - qpos[0, :2]
    assert np.linalg.norm(travel) == pytest.approx(np.linalg.norm(twin.qpos[-1, :2] - twin.qpos[0, :2]), rel=0.1)
    assert abs(np.dot(qpos[0, 3:7], twin.qpos[0, 3:7])) > 0.98  # the same heading: it walks forward, not sideways
    assert 0.85 < np.median(qpos[:, 2]) < 1.05 and report.max_penetration < 0.02
    assert report.contact_share > 0.5 and report.flags() == []


@needs_cmu
def test_the_script_writes_clips_and_their_quality(tmp_path):
    out = tmp_path / "expmap"
    subprocess.run([sys.executable, str(SCRIPT), str(WALK), "--out", str(out)], check=True, capture_output=True)
    clip = load_clip(out / "walking_1.npz")
    assert 2.5 < clip.seconds < 3.1  # 343 frames at 120 fps
    summary = (out / "import_summary.json").read_text()
    assert '"foot_slide_m_s"' in summary and '"flags": []' in summary
