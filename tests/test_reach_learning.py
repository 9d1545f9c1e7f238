"""PPO trains the brain-area model (`cortical`, AngoraPy's shadow brain with small areas) on the Shadow-hand reach
task (MJX, AngoraPy's relative joint-target control) in a short CPU run, through the user's path (`aj.train` of the
shipped `shadow_reach` config with overrides: tests/conftest.py's `cortical_reach`, which the probing tests share).

The task is the registered `ShadowHandReach` with its default physics and control; only episodes are shorter (30
policy steps, 0.6 s, instead of 100), so that 122,880 env steps hold some 4,100 goals. The run is sample-efficient
rather than large: 32 environments x 32 steps per cycle, 16 minibatch updates of 256 transitions per cycle, gamma
0.95 and no entropy bonus (the bonus only widens the 20-dimensional Gaussian).

No program here steps more than 32 hand environments at once: jaxlib 0.10.2's CPU Cholesky (MJX factors each
environment's 24 x 24 matrices) splits a batch whose cost, batch x 24^3 / 3, reaches 200,000 (44 or more
environments) over XLA's intra-op thread pool and blocks a pool thread until the pieces finish. On 2 cores the pool
has 2 threads, so two such Cholesky calls running side by side wait for each other forever (seen with 64: every
thread idle, the test never returns). tests/conftest.py also keeps XLA work off that pool.

The score is the mean goal distance (m, all 15 fingertip coordinates) at the end of 32 evaluation episodes with the
same goals for every policy: the trained policy acting deterministically (the Gaussian's mean) against three
references that need no learning: a uniformly random policy, the zero action (the joint targets follow the joints,
so the hand sags under gravity), and the distance at the start, which is what a policy that perfectly holds the
initial pose would score. Beating the start needs thumb and finger to move towards each other.
Measured on 2 CPU cores: random 0.137, zero 0.182, start 0.080, trained 0.044 (the `simple` MLP: 0.040), so the
bar (0.7 x 0.080 = 0.056) has a margin; training takes about 75 s there, compiling included.
"""

import jax
import numpy as np

import angora_jax as aj
from angora_jax.envs.core import Env
from angora_jax.envs.mujoco_task import Snapshot
from angora_jax.envs.random_rollout import random_action

EPISODE = 30
EVAL_EPISODES = 32  # at most 43 environments per program (see above)
# The trained policy's final goal distance must be below this share of the best of the three references.
BAR = 0.7


def baseline(env: Env, key: jax.Array, action_scale: jax.Array) -> dict[str, jax.Array]:
    """Mean return and final goal distance of one episode per environment under `action_scale` times uniform
    random actions (1: the random policy, 0: the zero action), and the mean goal distance at the start, from the
    same resets as `make_evaluate(key)`."""
    reset_key, act_key = jax.random.split(key)
    state = jax.vmap(env.reset)(jax.random.split(reset_key, EVAL_EPISODES))
    start = jax.vmap(env.task.goal_distance)(Snapshot.of(state.physics), state.info)

    def step(state, key):
        state = jax.vmap(env.step)(state, action_scale * random_action(env, key, EVAL_EPISODES))
        return state, (state.reward, state.done, state.metrics["goal_distance"])

    keys = jax.random.split(act_key, env.max_episode_steps)
    _, (rewards, dones, distances) = jax.lax.scan(step, state, keys)
    # Reach never terminates early: every episode ends at the last step, where the metrics are the final state's.
    return {"all_ended": dones[-1].min(), "episode_return": rewards.sum(0).mean(),
            "goal_distance": distances[-1].mean(), "start_distance": start.mean()}


def test_ppo_reach_beats_random_and_zero_policies(cortical_reach, quick_compiles):
    env = aj.make("ShadowHandReach", max_episode_steps=EPISODE)
    key = jax.random.key(123)
    run_baseline = jax.jit(baseline, static_argnums=0)
    random, zero = (run_baseline(env, key, scale) for scale in (1.0, 0.0))
    assert float(random["all_ended"]) == float(zero["all_ended"]) == 1.0

    agent = aj.load_agent(cortical_reach.run_dir, "latest")
    assert agent.config.ppo.network.name == "cortical" and agent.env.max_episode_steps == EPISODE
    trained = agent.evaluate(num_envs=EVAL_EPISODES, seed=123)  # the same resets as the baselines
    distances = {"random": float(random["goal_distance"]), "zero": float(zero["goal_distance"]),
                 "start": float(random["start_distance"]), "trained": trained["metric/goal_distance"]}
    print("final goal distance (m):", {name: round(d, 4) for name, d in distances.items()})
    bar = BAR * min(distances["random"], distances["zero"], distances["start"])
    assert distances["trained"] < bar, f"final goal distances {distances}: trained did not get below {bar:.4f}"
    assert trained["episode_return"] > max(float(random["episode_return"]), float(zero["episode_return"]))
    assert trained["episode_length"] == EPISODE
    # Training itself moved the fingers closer: the sampling policy's last cycles beat its first ones.
    history = cortical_reach.history
    sampled = [m["metric/goal_distance"] for m in history]
    tenth = len(sampled) // 10
    first, last = np.nanmean(sampled[:tenth]), np.nanmean(sampled[-tenth:])
    assert last < first, (first, last)
    assert history[-1]["env_steps"] == agent.config.ppo.num_cycles * 32 * 32
