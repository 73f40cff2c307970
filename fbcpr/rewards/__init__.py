"""Imitation rewards an RL agent trains on (AMP, NEAR, VIRL, progress); each owns its config section."""
