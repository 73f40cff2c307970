"""Tasks for the humanoid: the reward registry (App. C.3.1 names) and named goal poses (App. C.3.3)."""
from humanoid_env.tasks.goals import GOALS, goal_from_clip, goal_names, goal_obs, goal_qpos
from humanoid_env.tasks.rewards import CATEGORIES, TASKS, RewardFn, get_reward, list_families, task_category

__all__ = ["CATEGORIES", "GOALS", "TASKS", "RewardFn", "get_reward", "goal_from_clip", "goal_names", "goal_obs",
           "goal_qpos", "list_families", "task_category"]
