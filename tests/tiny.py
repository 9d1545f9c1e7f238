"""Overrides that shrink any shipped config to a few seconds of CPU training, shared by the experiment tests."""

TINY_PPO = [
    "ppo.num_envs=4",
    "ppo.rollout_length=16",
    "ppo.chunk_length=8",
    "ppo.minibatch_size=32",
    "ppo.num_epochs=1",
]
