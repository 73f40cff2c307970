"""What the trainer trains on: the env factory (humanoid or the toy point mass) and its task rewards."""
