"""lab/experiments/z_mix.py: every pair of prompts is mixed at every alpha, on the sphere, with the endpoints the
prompts themselves."""
import subprocess
import sys
from pathlib import Path

import numpy as np

from fbcpr import BFM
from fbcpr.inference.refine import project

SCRIPT = Path(__file__).parents[1] / "experiments" / "z_mix.py"


def test_mixes_of_every_pair_lie_on_the_sphere_between_their_prompts(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    zs = project(rng.standard_normal((3, BFM.pretrained().z_dim)))
    for i, z in enumerate(zs):
        np.save(tmp_path / f"z{i}.npy", z.astype(np.float32))
    specs = [f"z:{tmp_path / f'z{i}.npy'}" for i in range(3)]
    subprocess.run([sys.executable, str(SCRIPT), "pretrained", "--prompts", *specs, "--alphas", "0", "0.5", "1",
                    "--out", str(tmp_path / "mix")], capture_output=True, text=True, timeout=300, check=True)
    files = sorted((tmp_path / "mix").glob("*.npy"))
    assert len(files) == 3 * 3  # three pairs, three alphas
    pair = {a: np.load(tmp_path / "mix" / f"z-z0+z-z1@{a}.npy") for a in ("0", "0.5", "1")}
    np.testing.assert_allclose(pair["0"], zs[0], atol=1e-5)
    np.testing.assert_allclose(pair["1"], zs[1], atol=1e-5)
    np.testing.assert_allclose(pair["0.5"], project(zs[0] + zs[1]), atol=1e-5)
    for f in files:
        assert np.isclose(np.linalg.norm(np.load(f)), np.sqrt(zs.shape[1]), rtol=1e-4)
