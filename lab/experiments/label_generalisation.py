"""Can a policy learn an expert's labels from states it was not trained on? A plain behaviour-cloning fit, no RL.

    python lab/experiments/label_generalisation.py --train data/demos/getup-all data/demos/labels-sync \
        --test data/demos/labels-d1-600k

DAgger works when labels on the learner's states generalise to the states of the next learner. This fits the
TD3 actor's network (same layers, observations normalised by the training rows) to the behaviour-cloning targets
of the `--train` demonstration folders (an expert's labels where a rollout carries them, else its actions) by
mean squared error, then prints its error on every folder beside the error of the best constant: the training
targets' mean. A fit that loses to the constant on a `--test` folder learnt nothing that carries to those states.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from fbcpr.nn.networks import Stack
from motions.demonstrations import DemonstrationError, load_demonstrations


def rows(folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """The (observation, target) rows of a demonstration folder: labels where a rollout carries them."""
    demos = load_demonstrations(folder)
    obs = np.concatenate([d.clip.obs[:-1] for d in demos]).astype(np.float32)
    target = np.concatenate([d.target for d in demos]).astype(np.float32)
    return obs, target


def fit(obs: np.ndarray, target: np.ndarray, hidden: int, layers: int, steps: int, seed: int):
    """An actor-shaped regressor fitted to the rows; returns obs -> action."""
    torch.manual_seed(seed)
    mean, std = obs.mean(0), obs.std(0) + 1e-3
    net = Stack([obs.shape[1]] + [hidden] * layers + [target.shape[1]], 1, final=None)
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    x, y = torch.as_tensor((obs - mean) / std), torch.as_tensor(target)
    for _ in range(steps):
        i = torch.randint(len(x), (256,))
        loss = (torch.tanh(net(x[i])[0]) - y[i]).square().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()

    def predict(o: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return torch.tanh(net(torch.as_tensor((o - mean) / std))[0]).numpy()
    return predict


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--train", type=Path, nargs="+", required=True, help="demonstration folders to fit")
    ap.add_argument("--test", type=Path, nargs="+", required=True, help="demonstration folders held out")
    ap.add_argument("--steps", type=int, default=4000, help="Adam steps of 256 rows")
    ap.add_argument("--hidden", type=int, default=256)
    ap.add_argument("--layers", type=int, default=2, help="hidden layers (the TD3 actor's hidden_layers)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if args.steps < 1 or args.hidden < 1 or args.layers < 1:
        ap.error(f"--steps, --hidden and --layers must be >= 1, got {args.steps}, {args.hidden}, {args.layers}")
    torch.set_num_threads(args.threads)
    try:
        data = {p: rows(p) for p in args.train + args.test}
    except DemonstrationError as err:
        raise SystemExit(str(err)) from None
    obs = np.concatenate([data[p][0] for p in args.train])
    target = np.concatenate([data[p][1] for p in args.train])
    predict = fit(obs, target, args.hidden, args.layers, args.steps, args.seed)
    print(f"fitted to {len(obs):,} rows of {len(args.train)} folders; {args.steps} steps, "
          f"{args.layers} x {args.hidden}")
    print("| folder | role | rows | fit mse | constant (training mean) mse |\n|---|---|---:|---:|---:|")
    for p, (o, t) in data.items():
        role = "train" if p in args.train else "held out"
        print(f"| {p} | {role} | {len(o):,} | {np.square(predict(o) - t).mean():.3f} | "
              f"{np.square(target.mean(0) - t).mean():.3f} |")


if __name__ == "__main__":
    main()
