"""TD3 (Fujimoto et al. 2018) as the paper's single-task baseline (App. C.5.2) and the RL engine of the imitation
methods: one reward from the task registry, from an imitation reward, or a weighted sum of the two."""
