"""AMP/GAIfO-style adversarial imitation from observation: a discriminator on (s, s') transitions as a reward."""
