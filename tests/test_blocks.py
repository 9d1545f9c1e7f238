"""Policy blocks after SAPG (`ppo.blocks`, `angora_jax.ppo.blocks`): one block is plain PPO with today's layout; with
two the leader's loss holds the followers' transitions, blocks are contiguous ranges of environments (one per device
when there are as many devices), and evaluation acts with the leader. CartPole, feed-forward, one compiled cycle and
one evaluation shared by the file, compiled quickly."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from angora_jax.envs.classic import CartPole
from angora_jax.experiment.config import load_config
from angora_jax.nets import make_network
from angora_jax.ppo import PPOConfig, make_evaluate
from angora_jax.ppo.blocks import entropy_weights, environment_blocks, leader_off_policy_loss, row_blocks
from angora_jax.ppo.config import BlocksConfig
from angora_jax.ppo.cycle import build_head, build_model, make_cycle
from angora_jax.ppo.losses import LossInputs, ppo_loss

pytestmark = pytest.mark.usefixtures("quick_file_compiles")

# One update per cycle (one epoch, one minibatch of all 8 x 16 transitions), so the cycle's loss metrics are those of
# that update's minibatch and add up exactly.
PLAIN = PPOConfig(num_envs=8, rollout_length=16, chunk_length=8, minibatch_size=128, num_epochs=1)
BLOCKS = PLAIN.replace(blocks=BlocksConfig(count=2, embedding_size=4, leader_off_policy_weight=0.5,
                                           entropy_coefs=(0.0, 0.0)))


@pytest.fixture(scope="module")
def two_blocks():
    """The M = 2 run's state after one cycle, and that cycle's metrics."""
    init, cycle = make_cycle(CartPole(), None, BLOCKS)
    return cycle(init(jax.random.key(0)))


def test_one_block_is_plain_ppo_with_the_same_parameters_optimizer_state_and_program():
    """Runs saved before blocks existed restore: one block adds no parameter and no optimizer state, whatever the
    other block settings say, and compiles the plain cycle's program. (Run against the commit before blocks, the
    plain cycle's parameters, optimizer state and metrics after 2 cycles were bit-identical, simple and lstm.)"""
    one = PLAIN.replace(blocks=BlocksConfig(count=1, embedding_size=8, leader_off_policy_weight=3.0))
    (plain_init, plain_cycle), (one_init, one_cycle) = (make_cycle(CartPole(), None, c) for c in (PLAIN, one))
    plain, single = jax.eval_shape(plain_init, jax.random.key(0)), jax.eval_shape(one_init, jax.random.key(0))
    assert jax.tree.structure(plain) == jax.tree.structure(single)
    assert jax.tree.map(lambda x: x.shape, plain) == jax.tree.map(lambda x: x.shape, single)
    assert "block_embedding" not in plain.params
    assert plain_cycle.lower(plain).as_text() == one_cycle.lower(single).as_text()


def test_blocks_are_contiguous_environment_ranges_one_per_device_when_there_are_as_many():
    np.testing.assert_array_equal(environment_blocks(8, 2), [0, 0, 0, 0, 1, 1, 1, 1])
    np.testing.assert_array_equal(environment_blocks(8, 4), [0, 0, 1, 1, 2, 2, 3, 3])
    # The device axis as data parallelism names it (`local_share` under shard_map), here mapped by vmap.
    per_device = jax.vmap(lambda _: environment_blocks(8, 2, "devices"), axis_name="devices")(jnp.arange(2))
    np.testing.assert_array_equal(per_device, [[0, 0, 0, 0], [1, 1, 1, 1]])
    # A minibatch tile's rows, chunk after chunk as tbptt.gather_carries orders them.
    np.testing.assert_array_equal(row_blocks(environment_blocks(8, 2), jnp.array([1, 6]), 2), [0, 1, 0, 1])


def one_step(advantages):
    """A minibatch of one step of 4 rows, rows 0-1 the leader's, 2-3 a follower's: the head, the leader's logits,
    the loss inputs and the rows' blocks."""
    logits = jnp.array([[[0.3, -0.2], [0.1, 0.4], [-0.5, 0.2], [0.7, 0.0]]])
    batch = LossInputs(actions=jnp.array([[0, 1, 1, 0]]), log_probs=jnp.log(jnp.full((1, 4), 0.5)),
                       values=jnp.zeros((1, 4)), advantages=jnp.asarray([advantages]), targets=jnp.zeros((1, 4)))
    return build_head(CartPole(), PLAIN), logits, batch, jnp.array([0, 0, 1, 1])


def off_policy_term(advantages, rows=slice(0, 4)):
    """The leader's off-policy term (weight 0.5, M = 2) on `one_step`'s `rows`."""
    head, logits, batch, blocks = one_step(advantages)
    return leader_off_policy_loss(head, logits[:, rows], jax.tree.map(lambda x: x[:, rows], batch), blocks[rows],
                                  0.2, 0.5, 2)


def test_the_leaders_off_policy_term_reads_the_followers_transitions_and_not_its_own():
    base, parts = off_policy_term([1.0, -1.0, 0.5, 2.0])
    assert float(off_policy_term([9.0, 9.0, 0.5, 2.0])[0]) == float(base), "the leader's own rows do not count here"
    assert float(off_policy_term([1.0, -1.0, -3.0, 2.0])[0]) != pytest.approx(float(base))
    # weight / M times the mean clipped objective over the follower rows, by hand:
    ratios = np.exp(np.array([jax.nn.log_softmax(jnp.array([-0.5, 0.2]))[1],
                              jax.nn.log_softmax(jnp.array([0.7, 0.0]))[0]]) - np.log(0.5))
    objective = np.minimum(ratios * [0.5, 2.0], np.clip(ratios, 0.8, 1.2) * [0.5, 2.0])
    assert float(parts["leader_off_policy_loss"]) == pytest.approx(-objective.mean(), rel=1e-5)
    assert float(base) == pytest.approx(0.5 / 2 * -objective.mean(), rel=1e-5)


def test_devices_holding_whole_blocks_average_to_the_whole_minibatchs_off_policy_term():
    """Under data parallelism device 0 holds the leader's rows alone and the others the followers': the mean of the
    devices' terms (gradients are averaged the same way) must be the whole minibatch's term, with no 0 / 0."""
    advantages = [1.0, -1.0, 0.5, 2.0]
    whole = off_policy_term(advantages)[0]
    shares = [off_policy_term(advantages, rows)[0] for rows in (slice(0, 2), slice(2, 4))]
    assert float(shares[0]) == 0.0
    assert float((shares[0] + shares[1]) / 2) == pytest.approx(float(whole), rel=1e-6)


def test_each_row_weighs_its_entropy_by_its_blocks_weight():
    head = build_head(CartPole(), PLAIN)
    logits = jnp.array([[[0.0, 0.0], [2.0, -2.0]]])
    batch = LossInputs(*(jnp.zeros((1, 2)),) * 5)
    weights = entropy_weights(BlocksConfig(count=2, entropy_coefs=(0.0, 0.03)), jnp.float32(0.01), jnp.array([0, 1]))
    loss, parts = ppo_loss(head, logits, jnp.zeros((1, 2)), batch.replace(actions=jnp.zeros((1, 2), int)), 0.2, 1.0,
                           weights, False)
    entropies = head.entropy(logits)[0]
    assert float(loss) == pytest.approx(-0.03 * float(entropies[1]) / 2, rel=1e-6)
    assert float(parts["entropy"]) == pytest.approx(float(entropies.mean()))
    assert float(entropy_weights(BlocksConfig(count=2), jnp.float32(0.01), jnp.array([0, 1]))) == pytest.approx(0.01)


def test_with_two_blocks_the_cycles_loss_adds_the_leaders_off_policy_term_and_reports_each_block(two_blocks):
    _, metrics = two_blocks
    m = {name: float(value) for name, value in metrics.items()}
    assert m["leader_off_policy_loss"] != 0.0
    # The loss is plain PPO's (no entropy weight in either block here) plus weight / M times the off-policy mean.
    plain_loss = m["policy_loss"] + PLAIN.value_coef * m["value_loss"]
    assert m["loss"] == pytest.approx(plain_loss + 0.5 / 2 * m["leader_off_policy_loss"], abs=1e-6)
    for name in ("episodes", "episode_return", "episode_length"):
        assert f"block0/{name}" in m and f"block1/{name}" in m
        assert m[name] == m[f"block0/{name}"] or np.isnan(m[name]) and np.isnan(m[f"block0/{name}"])
    assert m["episodes"] + m["block1/episodes"] > 0


def test_evaluation_acts_with_the_leader(two_blocks):
    """Setting the follower's embedding leaves evaluation as it was; setting the leader's changes it."""
    state, _ = two_blocks
    evaluate = make_evaluate(CartPole(), None, BLOCKS, num_envs=8, per_episode=True)

    def lengths(block: int, value: float):
        embedding = state.params["block_embedding"]["embedding"].at[block].set(value)
        params = {**state.params, "block_embedding": {"embedding": embedding}}
        return np.asarray(evaluate(state.replace(params=params), jax.random.key(1))["episode_length"])

    as_trained = np.asarray(evaluate(state, jax.random.key(1))["episode_length"])
    np.testing.assert_array_equal(lengths(1, 50.0), as_trained)
    assert not np.array_equal(lengths(0, 50.0), as_trained)


def test_the_model_without_a_block_is_the_leader():
    model = build_model(make_network(PLAIN.network), build_head(CartPole(), PLAIN), BLOCKS)
    obs = jax.vmap(CartPole().reset)(jax.random.split(jax.random.key(2), 3)).obs
    carry = model.initial_carry(3)
    params = model.init(jax.random.key(0), carry, obs)["params"]
    leader = model.apply({"params": params}, carry, obs)[1]
    np.testing.assert_array_equal(leader, model.apply({"params": params}, carry, obs, block=jnp.zeros(3, int))[1])
    assert not np.allclose(leader, model.apply({"params": params}, carry, obs, block=jnp.ones(3, int))[1])


@pytest.mark.parametrize("overrides, message", [
    (["ppo.blocks.count=3"], "must divide the minibatch tile"),
    (["ppo.blocks.count=2", "ppo.blocks.entropy_coefs=[0.1]"], "one weight per block"),
    (["ppo.blocks.count=2", "ppo.blocks.entropy_coefs=[0.0, 0.1]", "ppo.entropy_coef_final=0.0"], "set one of them"),
    (["ppo.blocks.entropy_coefs=[0.1]"], "ppo.blocks.count is 1"),
])
def test_block_settings_that_cannot_apply_are_refused(overrides, message):
    with pytest.raises(ValueError, match=message):
        load_config("cartpole", ["ppo.num_envs=8", "ppo.minibatch_size=128", "ppo.rollout_length=16",
                                 "ppo.chunk_length=8", *overrides]).ppo.validate()


def test_the_config_reads_a_blocks_section():
    blocks = load_config("cartpole", ["ppo.blocks.count=2", "ppo.blocks.entropy_coefs=[0.0, 0.01]"]).ppo.blocks
    assert blocks == BlocksConfig(count=2, entropy_coefs=(0.0, 0.01))
