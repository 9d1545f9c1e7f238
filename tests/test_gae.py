"""GAE against a direct loop, with termination (no bootstrap) and truncation (bootstrap from final_obs)."""

import jax
import numpy as np

from angora_jax.ppo.gae import gae, next_values


def reference(rewards, values, last_value, final_values, dones, truncated, gamma, lam):
    steps, envs = rewards.shape
    advantages = np.zeros((steps, envs))
    for n in range(envs):
        running = 0.0
        for t in reversed(range(steps)):
            if dones[t, n]:
                following = final_values[t, n] if truncated[t, n] else 0.0
                running = 0.0
            else:
                following = values[t + 1, n] if t + 1 < steps else last_value[n]
            delta = rewards[t, n] + gamma * following - values[t, n]
            running = delta + gamma * lam * running
            advantages[t, n] = running
    return advantages


def test_gae_matches_reference_loop_with_terminations_and_truncations():
    keys = jax.random.split(jax.random.key(0), 4)
    steps, envs = 12, 3
    rewards = np.asarray(jax.random.normal(keys[0], (steps, envs)))
    values = np.asarray(jax.random.normal(keys[1], (steps, envs)))
    final_values = np.asarray(jax.random.normal(keys[2], (steps, envs)))
    last_value = np.asarray(jax.random.normal(keys[3], (envs,)))
    dones = np.zeros((steps, envs), np.float32)
    truncated = np.zeros((steps, envs), np.float32)
    dones[3, 0] = dones[8, 1] = dones[11, 2] = dones[5, 2] = 1.0
    truncated[8, 1] = truncated[11, 2] = 1.0
    following = next_values(values, last_value, final_values, dones, truncated)
    advantages, targets = gae(rewards, values, following, dones, gamma=0.9, lam=0.8)
    expected = reference(rewards, values, last_value, final_values, dones, truncated, 0.9, 0.8)
    np.testing.assert_allclose(advantages, expected, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(targets, expected + values, rtol=1e-5, atol=1e-5)
