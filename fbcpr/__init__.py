"""FB-CPR: a behavioral foundation model for a simulated SMPL humanoid."""

__version__ = "0.1.0"
