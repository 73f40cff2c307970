"""NPMP: neural probabilistic motor primitives (Merel et al. 2019) distilled from a BFM's tracking policy.

`config` (sizes and objective), `model` (encoder, AR(1) prior, decoder), `data` (expert rollouts: BC from noisy
rollouts and LFPC, one safetensors format), `distill` (training with checkpoints and resume), `checkpoint`,
`agent` (one-shot tracking as an evaluation Agent), `evaluate` (scores relative to the expert) and `latent_opt`
(optimising a clip's latent sequence, Sec. 3.3).
"""
