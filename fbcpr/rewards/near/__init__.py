"""NEAR (Diwan et al.): a noise-conditioned energy of expert (s, s') transitions, learned offline by denoising score
matching, as an annealed imitation reward (`fbcpr.core.protocols.ImitationReward`, registered as "near")."""
