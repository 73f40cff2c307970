"""Data-parallel training (fbcpr.nn.distributed) on 2 CPU ranks over gloo: identical replicas, the split update equals
the single-process one, exact normaliser merge, sharded priorities, and a killed rank ending the run cleanly."""
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.multiprocessing as mp
from safetensors.torch import load_file, save_file

from fbcpr.nn import distributed
from fbcpr.core.checkpoint import load_checkpoint
from fbcpr.core.config import config_from_dict
from fbcpr.core.errors import ConfigError
from fbcpr.core.schema import dump_config
from fbcpr.nn.normalizer import RunningNormalizer
from fbcpr.methods.td3.agent import TD3Agent
from fbcpr.envs import toy as pm
from fbcpr.train.trainer import Trainer

torch.set_num_threads(1)
ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def rank_env(rank: int, world: int, port: int) -> dict[str, str]:
    """What torchrun puts in each worker's environment."""
    return {"RANK": str(rank), "WORLD_SIZE": str(world), "LOCAL_RANK": str(rank), "LOCAL_WORLD_SIZE": str(world),
            "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(port)}


def fbcpr_cfg(**train):
    return config_from_dict({
        "model": {"preset": "tiny"},
        "agent": {"batch_size": 16},
        "env": {"name": "toy", "max_episode_steps": 30},
        "train": {"total_env_steps": 96, "num_envs": 4, "warmup_steps": 32, "rollout_steps": 16,
                  "updates_per_rollout": 3, "buffer_capacity": 500, "z_update_every": 7, "priority_every": 64,
                  "eval_every": 0, "checkpoint_every": 0, "log_every": 32, "reward_buffer_size": 20,
                  "torch_threads": 1, "dist_timeout_s": 60, **train},
    })


def amp_cfg():
    return config_from_dict({
        "algorithm": "td3",
        "model": {"hidden_dim": 16, "hidden_layers": 1},
        "agent": {"batch_size": 16, "seq_length": 4, "reward": {"task": "reach-top-right", "imitation": "amp"},
                  "amp": {"hidden_dim": 16, "hidden_layers": 1}},
        "env": {"name": "toy", "motions": "circle-ccw", "max_episode_steps": 30},
        "train": {"total_env_steps": 96, "num_envs": 4, "warmup_steps": 32, "rollout_steps": 16,
                  "updates_per_rollout": 3, "buffer_capacity": 500, "priority_every": 0, "eval_every": 0,
                  "checkpoint_every": 0, "log_every": 32, "reward_buffer_size": 0, "torch_threads": 1,
                  "dist_timeout_s": 60},
    })


def learner_state(tr: Trainer) -> dict[str, torch.Tensor]:
    tensors, meta = tr.agent.state()
    return {k: v.detach().cpu().contiguous().clone() for k, v in tr._learner_state(tensors, meta).items()}


# ------------------------------------------------------------------------------------------ spawned workers
def _train_worker(rank: int, world: int, ports: list[int], out: str) -> None:
    for port, (name, cfg) in zip(ports, (("fbcpr", fbcpr_cfg()), ("amp", amp_cfg()))):
        os.environ.update(rank_env(rank, world, port))
        tr = Trainer(cfg, Path(out) / name, progress=False)
        summary = tr.run()
        state = learner_state(tr)
        state["rank_obs"] = torch.as_tensor(np.asarray(tr.buffer.data["obs"][: len(tr.buffer)]))
        state["priorities"] = torch.as_tensor(np.asarray(tr.bundle.library.priorities, dtype=np.float64))
        state["summary"] = torch.tensor([summary["env_steps"], summary["updates"], len(tr.emd),
                                         len(tr.bundle.library.names)])
        tr.replicas.close()
        save_file(state, str(Path(out) / f"{name}_rank{rank}.safetensors"))


def split_batch() -> tuple[dict[str, torch.Tensor], torch.Tensor]:
    """A fixed global batch of 32 toy transitions (and its expert windows)."""
    g = torch.Generator().manual_seed(5)
    n = 32
    batch = {"obs": torch.randn(n, pm.OBS_DIM, generator=g), "action": torch.rand(n, pm.ACTION_DIM, generator=g) * 2 - 1,
             "next_obs": torch.randn(n, pm.OBS_DIM, generator=g), "qpos": torch.zeros(n, pm.NQ),
             "qvel": torch.zeros(n, pm.NV), "terminated": (torch.rand(n, generator=g) < 0.2).float()}
    return batch, torch.zeros(4, 4, pm.OBS_DIM)


def td3_agent() -> TD3Agent:
    cfg = config_from_dict({"algorithm": "td3", "model": {"hidden_dim": 16, "hidden_layers": 1, "obs_dim": pm.OBS_DIM,
                                                          "action_dim": pm.ACTION_DIM, "actor_noise_clip": 1e-9},
                            "agent": {"batch_size": 32, "reward": {"task": "reach-top-right"}}})
    task = pm.get_task("reach-top-right")
    return TD3Agent(cfg.model, cfg.agent, seed=3, task_reward=lambda next_obs, qpos, qvel: task(next_obs))


def agent_state(agent: TD3Agent) -> dict[str, torch.Tensor]:
    out = {f"model.{k}": v.clone() for k, v in agent.model.state_dict().items()}
    out.update({f"grad.{n}": p.grad.clone() for n, p in agent.model.named_parameters() if p.grad is not None})
    return out


def normalizer_shard(rank: int) -> torch.Tensor:
    """Unequal shards (7 and 13 rows) with different means, so a plain average of the ranks' moments would be wrong."""
    return torch.randn(7 + 6 * rank, 5, generator=torch.Generator().manual_seed(rank)) * (1 + rank) + 3 * rank


def _agent_worker(rank: int, world: int, port: int, out: str) -> None:
    os.environ.update(rank_env(rank, world, port))
    replicas, _ = distributed.setup(torch.device("cpu"), 60.0)
    batch, windows = split_batch()
    half = {k: v.chunk(world)[rank] for k, v in batch.items()}
    agent = td3_agent()
    with replicas.synchronized():
        agent.update(half, windows)
    norm = RunningNormalizer(5)
    norm.update(torch.ones(3, 5))  # earlier statistics, the same on every rank
    with replicas.synchronized():
        norm.update(normalizer_shard(rank))
    state = agent_state(agent)
    state.update({f"norm.{k}": v for k, v in norm.state_dict().items()})
    replicas.close()
    save_file(state, str(Path(out) / f"agent_rank{rank}.safetensors"))


def _worker(rank: int, world: int, ports: list[int], out: str) -> None:
    """One pair of processes for every 2-rank check (starting processes is what costs here)."""
    torch.set_num_threads(1)
    _agent_worker(rank, world, ports[0], out)
    _train_worker(rank, world, ports[1:], out)


@pytest.fixture(scope="module")
def two_ranks(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("two_ranks")
    mp.spawn(_worker, args=(2, [free_port() for _ in range(3)], str(out)), nprocs=2, join=True)
    return out


# ------------------------------------------------------------------------------------------ tests
def test_two_ranks_stay_bit_identical_on_their_own_data(two_ranks):
    tmp_path = two_ranks
    for name in ("fbcpr", "amp"):
        r0, r1 = (load_file(str(tmp_path / f"{name}_rank{r}.safetensors")) for r in (0, 1))
        env_steps, updates, tracked, clips = r0["summary"].tolist()
        assert env_steps == 96 and updates == 3 * 5  # global steps: phases of 16 end at 32 (warm-up), 48, ..., 96
        for k in r0:
            if k != "rank_obs":
                assert torch.equal(r0[k], r1[k]), f"{name}: {k} differs between the ranks"
        assert r0["rank_obs"].shape == r1["rank_obs"].shape == (48, pm.OBS_DIM)  # each rank holds half the steps
        assert not torch.equal(r0["rank_obs"], r1["rank_obs"])  # ... of its own envs
        keys = [k for k in r0 if "optim" in k]
        assert keys and any(r0[k].abs().sum() > 0 for k in keys)  # the optimisers stepped
        if name == "amp":  # the imitation reward's own optimiser and normalisers are kept in step too
            assert any(k.startswith("imitation.discriminator") for k in r0)
            assert any(k.startswith("imitation.optim") for k in r0)
        out = tmp_path / name
        assert (out / "metrics.csv").exists() and (out / "checkpoints" / "latest").exists()
        assert load_checkpoint(out / "checkpoints" / (out / "checkpoints" / "latest").read_text().strip())
        assert not list(out.glob("*rank1*"))  # rank 1 writes nothing into the run directory
    tracked, clips = load_file(str(tmp_path / "fbcpr_rank0.safetensors"))["summary"].tolist()[2:]
    assert clips > 1 and tracked == clips  # each rank tracked its share of the clips; both got every score


def test_split_update_equals_single_process_update_and_normaliser_merges_exactly(two_ranks):
    r0, r1 = (load_file(str(two_ranks / f"agent_rank{r}.safetensors")) for r in (0, 1))
    batch, windows = split_batch()
    single = td3_agent()
    before = {k: v.clone() for k, v in single.model.state_dict().items()}
    single.update(batch, windows)
    ref = agent_state(single)
    assert {k for k in ref if k.startswith("grad.")} == {k for k in r0 if k.startswith("grad.")}
    for k, v in ref.items():
        assert torch.equal(r0[k], r1[k]), k
        torch.testing.assert_close(r0[k], v, rtol=1e-5, atol=1e-6, msg=k)
    assert any(not torch.equal(before[k[6:]], ref[k]) for k in ref if k.startswith("model."))  # it did learn
    union = RunningNormalizer(5)
    union.update(torch.ones(3, 5))
    union.update(torch.cat([normalizer_shard(0), normalizer_shard(1)]))
    for k, v in union.state_dict().items():
        torch.testing.assert_close(r0[f"norm.{k}"], v, rtol=1e-12, atol=1e-12)
        assert torch.equal(r0[f"norm.{k}"], r1[f"norm.{k}"])
    assert r0["norm.count"].item() == 3 + 7 + 13


def test_a_two_rank_checkpoint_resumes_on_one_process(two_ranks, tmp_path):
    import shutil

    run = tmp_path / "fbcpr"
    shutil.copytree(two_ranks / "fbcpr", run)
    meta = load_checkpoint(run / "checkpoints" / "step_0000000096").trainer_state()[1]
    assert meta["world_size"] == 2 and meta["updates"] == 15
    tr = Trainer(fbcpr_cfg(total_env_steps=144), run, resume=True, progress=False)
    assert tr.replicas.world_size == 1 and tr.learner.updates == 15
    summary = tr.run()
    # no replay buffer in the checkpoint: 32 env steps (the warm-up) refill it, then phases ending at 128 and 144
    assert summary["env_steps"] == 144 and summary["updates"] == 15 + 2 * 3


def test_world_size_and_backend_limits_are_config_errors(monkeypatch):
    from fbcpr.train.schedule import check_world_size

    check_world_size(fbcpr_cfg(), 4)  # 16 steps = 4 ranks x 4 envs
    with pytest.raises(ConfigError, match=r"^train.rollout_steps: .* world sizes that fit: \[1, 2, 4\]"):
        check_world_size(fbcpr_cfg(), 3)
    with pytest.raises(ConfigError, match="^train.save_buffer"):
        check_world_size(fbcpr_cfg(save_buffer=True), 2)
    assert distributed.setup(torch.device("cpu"), 5.0)[0].world_size == 1  # no torchrun: nothing to join
    monkeypatch.setenv("WORLD_SIZE", "2")
    monkeypatch.setenv("RANK", "0")
    monkeypatch.setenv("LOCAL_WORLD_SIZE", "2")
    with pytest.raises(ConfigError, match="^train.dist_backend: NCCL needs one GPU per process"):
        distributed.setup(torch.device("cpu"), 5.0, "nccl")


def two_rank_train(config: Path, run: Path) -> list[subprocess.Popen]:
    """`fbcpr train CONFIG --out RUN` as the 2 ranks torchrun would start, on a free local port."""
    port = free_port()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    return [subprocess.Popen([sys.executable, "-m", "fbcpr", "train", str(config), "--out", str(run), "--no-progress"],
                             env={**env, **rank_env(r, 2, port)}, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True) for r in (0, 1)]


def test_a_killed_rank_ends_the_others_with_a_clear_error_and_keeps_the_checkpoint(tmp_path):
    cfg = fbcpr_cfg(total_env_steps=10**6, checkpoint_every=32, log_every=10**5, priority_every=0,
                    dist_timeout_s=30)
    (tmp_path / "cfg.yaml").write_text(dump_config(cfg))
    run = tmp_path / "run"
    procs = two_rank_train(tmp_path / "cfg.yaml", run)
    try:
        deadline = time.monotonic() + 60
        while not list((run / "checkpoints").glob("step_*")) and time.monotonic() < deadline:
            assert all(p.poll() is None for p in procs), [p.communicate() for p in procs]
            time.sleep(0.2)
        procs[1].send_signal(signal.SIGKILL)
        _, err = procs[0].communicate(timeout=45)  # not a hang: gloo sees the peer go, the timeout catches a hung one
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    assert procs[0].returncode == 1
    assert "rank 0 of 2: lost the other ranks" in " ".join(err.split()), err
    latest = run / "checkpoints" / (run / "checkpoints" / "latest").read_text().strip()
    ck = load_checkpoint(latest)
    assert ck.trainer_state()[1]["world_size"] == 2 and ck.trainer_state()[1]["env_steps"] % 32 == 0


def test_rank_0_says_what_a_torchrun_run_runs_and_the_summary_records_the_world_size(tmp_path):
    cfg = fbcpr_cfg(num_envs=2)  # 16 env steps a phase: 2 ranks x 2 envs x 4 steps
    (tmp_path / "cfg.yaml").write_text(dump_config(cfg))
    run = tmp_path / "run"
    procs = two_rank_train(tmp_path / "cfg.yaml", run)
    logs = [p.communicate(timeout=120) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], logs
    plan = ("data-parallel: 2 processes (gloo), each with 2 envs and a batch of 16 (4 envs and 32 samples per update "
            "in all); 3 updates per 16 env steps over all processes: a global update-to-data ratio of 0.188")
    assert plan in logs[0][1] and "data-parallel" not in logs[1][1]
    assert json.loads((run / "summary.json").read_text())["world_size"] == 2
    latest = run / "checkpoints" / (run / "checkpoints" / "latest").read_text().strip()
    assert load_checkpoint(latest).trainer_state()[1]["world_size"] == 2
