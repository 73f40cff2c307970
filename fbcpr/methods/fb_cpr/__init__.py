"""FB-CPR (the paper's method): forward-backward representation with conditional policy regularisation.

`model` (networks to act and prompt), `losses` (Algorithm 1's FB-specific terms), `agent` (one update),
`imitation` (its discriminator as an `ImitationReward`).
"""
