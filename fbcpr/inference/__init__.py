"""Using a trained model: BFM, prompts (reward, goal, tracking), stored prompts, timelines, refinement, weight mixes."""
