"""The one online training loop: rollouts, replay buffer, device batches, checkpoints, evaluations."""
