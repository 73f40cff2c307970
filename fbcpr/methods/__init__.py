"""Online methods the trainer drives (FB-CPR, TD3); each owns its config, model and agent."""
