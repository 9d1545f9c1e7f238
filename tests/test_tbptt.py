"""Truncated BPTT: chunk gradients equal full BPTT when s = T, truncation cuts gradients at chunk borders, the
carry resets at episode starts, the rollout's stored carries replay exactly, and minibatch tiling."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from angora_jax.envs.classic import CartPole
from angora_jax.envs.core import ActionSpec, Sensation
from angora_jax.nets import ActorCritic, make_network
from angora_jax.ppo import NetworkConfig, PPOConfig, make_head, tile_shape
from angora_jax.ppo.normalization import observation_stats
from angora_jax.ppo.rollout import ActorState, make_rollout
from angora_jax.ppo.tbptt import gather_carries, gather_sequences, minibatch_indices, unroll

T, B = 8, 3

# Every program here runs a few steps or a cycle or two (tests/quick_compile.py).
pytestmark = pytest.mark.usefixtures("quick_file_compiles")


@pytest.fixture(scope="module")
def setup():
    network = make_network(NetworkConfig(name="lstm", width=8, cell_size=8))
    model = ActorCritic(network, make_head("gaussian", ActionSpec(low=-jnp.ones(2), high=jnp.ones(2))))
    k1, k2, k3, k4 = jax.random.split(jax.random.key(0), 4)
    obs = Sensation.make(proprioception=jax.random.normal(k1, (T, B, 5)), asymmetric=jax.random.normal(k2, (T, B, 2)))
    params = model.init(k3, network.initial_carry(B), jax.tree.map(lambda x: x[0], obs))["params"]
    weights = jax.random.normal(k4, (T, B, model.head.num_params + 1))
    return network, model, obs, params, weights


def chunk_outputs(setup, params, obs, resets, start_carry):
    """The cycle's path: unroll a batch of chunks from stored carries; policy parameters and value, `(s, rows, P+1)`."""
    network, model, _, _, _ = setup
    _, policy, values = unroll(
        lambda c, o: model.apply({"params": params}, c, o),
        jax.lax.stop_gradient(start_carry),
        network.initial_carry(start_carry["policy"][0].shape[0]),
        obs,
        resets,
    )
    return jnp.concatenate([policy, values[..., None]], -1)


def full_bptt_loss(setup, params, resets):
    """Reference: a plain Python loop over all T steps, zeroing the carry (zeros is the LSTM's initial carry)."""
    network, model, obs, _, weights = setup
    carry = network.initial_carry(B)
    outputs = []
    for t in range(T):
        keep = 1.0 - resets[t][:, None]
        carry = jax.tree.map(lambda c, keep=keep: c * keep, carry)
        carry, policy, value = model.apply({"params": params}, carry, jax.tree.map(lambda x, t=t: x[t], obs))
        outputs.append(jnp.concatenate([policy, value[:, None]], -1))
    return (jnp.stack(outputs) * weights).sum()


def as_chunks(x, s):
    return x.reshape((T // s, s) + x.shape[1:])


RESETS = jnp.zeros((T, B)).at[3, 1].set(1.0).at[6, 2].set(1.0)


@pytest.mark.slow
def test_chunk_gradients_equal_full_bptt_when_chunk_is_the_rollout(setup):
    network, _, obs, params, _ = setup
    data = jax.tree.map(lambda x: as_chunks(x, T), (obs, RESETS))
    carries = jax.tree.map(lambda x: x[None], network.initial_carry(B))
    chunk, env = jnp.array([0]), jnp.arange(B)
    seq_obs, seq_resets = gather_sequences(data, chunk, env)
    start = gather_carries(carries, chunk, env)
    weights = setup[4]
    grads = jax.grad(lambda p: (chunk_outputs(setup, p, seq_obs, seq_resets, start) * weights).sum())(params)
    expected = jax.grad(lambda p: full_bptt_loss(setup, p, RESETS))(params)
    for got, want in zip(jax.tree.leaves(grads), jax.tree.leaves(expected), strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5)


@pytest.mark.slow
def test_shorter_chunks_replay_the_same_forward_pass_but_cut_gradients(setup):
    network, _, obs, params, _ = setup
    s = T // 2
    # Stored carries as the rollout keeps them: the carry at each chunk start, from a forward pass over everything.
    first_half = jax.tree.map(lambda x: x[:s], obs)
    mid_carry, _, _ = unroll(
        lambda c, o: setup[1].apply({"params": params}, c, o),
        network.initial_carry(B),
        network.initial_carry(B),
        first_half,
        RESETS[:s],
    )
    carries = jax.tree.map(lambda a, b: jnp.stack([a, b]), network.initial_carry(B), mid_carry)
    data = jax.tree.map(lambda x: as_chunks(x, s), (obs, RESETS))
    chunk, env = jnp.arange(2), jnp.arange(B)
    seq_obs, seq_resets = gather_sequences(data, chunk, env)
    start = gather_carries(carries, chunk, env)

    def loss(p):
        out = chunk_outputs(setup, p, seq_obs, seq_resets, start)
        # Back from (s, chunks * B) to (T, B) so the loss weights line up with the full-BPTT reference.
        out = out.reshape(s, 2, B, -1).swapaxes(0, 1).reshape(T, B, -1)
        return (out * setup[4]).sum()

    np.testing.assert_allclose(loss(params), full_bptt_loss(setup, params, RESETS), rtol=1e-5)
    grads = jax.grad(loss)(params)
    expected = jax.grad(lambda p: full_bptt_loss(setup, p, RESETS))(params)
    kernel = grads["network"]["policy_cell"]["hi"]["kernel"]
    assert not np.allclose(kernel, expected["network"]["policy_cell"]["hi"]["kernel"], rtol=1e-3)


@pytest.mark.slow
def test_carry_resets_where_an_episode_starts(setup):
    network, model, obs, params, _ = setup
    k = 4
    resets = jnp.zeros((T, B)).at[k].set(1.0)

    def run(o, r):
        step = lambda c, x: model.apply({"params": params}, c, x)  # noqa: E731
        return unroll(step, network.initial_carry(B), network.initial_carry(B), o, r)[1]

    after_reset = run(obs, resets)[k:]
    fresh = run(jax.tree.map(lambda x: x[k:], obs), resets[k:])
    np.testing.assert_allclose(after_reset, fresh, rtol=1e-5, atol=1e-6)
    without_reset = run(obs, jnp.zeros((T, B)))[k:]
    assert not np.allclose(without_reset, fresh, atol=1e-4)


def test_rollout_stored_carries_and_resets_replay_the_acting_log_probs():
    env = CartPole()
    num_envs, chunks, s = 4, 4, 16
    network = make_network(NetworkConfig(name="gru", width=8, cell_size=8))
    head = make_head("categorical", env.action_spec)
    model = ActorCritic(network, head)

    def apply_fn(p, c, o):
        return model.apply({"params": p}, c, o)

    initial = network.initial_carry(num_envs)
    rollout = jax.jit(make_rollout(env, apply_fn, head, initial, chunks, s, normalize_obs=True, clip=10.0))
    env_state = jax.vmap(env.reset)(jax.random.split(jax.random.key(0), num_envs))
    params = model.init(jax.random.key(1), initial, env_state.obs)["params"]
    zeros = jnp.zeros(num_envs)
    actor = ActorState(env_state, initial, zeros, zeros)
    _, _, traj, start_carries, _ = rollout(
        params, observation_stats(env.observation_shapes()), actor, jax.random.split(jax.random.key(2), num_envs)
    )
    assert float(traj.resets.sum()) > 0  # random CartPole episodes are short, so episodes end inside chunks

    @jax.jit
    def replay(resets):
        chunk, env_index = jnp.arange(chunks), jnp.arange(num_envs)
        obs, resets = gather_sequences((traj.obs, resets), chunk, env_index)
        actions = gather_sequences(traj.actions, chunk, env_index)
        start = gather_carries(start_carries, chunk, env_index)
        step = lambda c, o: apply_fn(params, c, o)  # noqa: E731
        _, policy, _ = unroll(step, start, network.initial_carry(chunks * num_envs), obs, resets)
        return head.log_prob(policy, actions)

    expected = gather_sequences(traj.log_probs, jnp.arange(chunks), jnp.arange(num_envs))
    np.testing.assert_allclose(replay(traj.resets), expected, rtol=1e-5, atol=1e-5)
    assert not np.allclose(replay(jnp.zeros_like(traj.resets)), expected, rtol=1e-5, atol=1e-5)


def test_minibatch_indices_partition_the_grid_every_epoch():
    env_index, chunk_index = minibatch_indices(jax.random.key(0), 6, 4, (3, 2))
    assert env_index.shape == (4, 3) and chunk_index.shape == (4, 2)
    pairs = {(int(e), int(c)) for es, cs in zip(env_index, chunk_index, strict=True) for e in es for c in cs}
    assert pairs == {(e, c) for e in range(6) for c in range(4)}
    # Stratified: column b of every tile is a trajectory of block b (trajectories 2b and 2b + 1).
    np.testing.assert_array_equal(env_index // 2, np.broadcast_to(np.arange(3), (4, 3)))
    # ... and the blocks are shuffled: across epochs both orders of some block occur.
    orders = {tuple(minibatch_indices(jax.random.key(k), 6, 4, (3, 2))[0][::2, 0].tolist()) for k in range(8)}
    assert orders == {(0, 1), (1, 0)}


def test_minibatches_take_the_chunk_positions_in_a_new_random_grouping_every_epoch():
    """Chunk positions are shuffled before they are cut into groups of m: each epoch uses every chunk once, but which
    chunks share a minibatch, and which come first, changes with the key (not always the rollout's early chunks
    together, in the first update)."""
    epochs = [np.asarray(minibatch_indices(jax.random.key(k), 2, 6, (2, 2))[1]) for k in range(8)]
    for chunk_index in epochs:
        assert chunk_index.shape == (3, 2)
        np.testing.assert_array_equal(np.sort(chunk_index.ravel()), np.arange(6))
    groupings = {frozenset(frozenset(row) for row in chunk_index.tolist()) for chunk_index in epochs}
    assert len(groupings) > 1, "the same chunks share a minibatch in every epoch"
    assert len({tuple(chunk_index[0]) for chunk_index in epochs}) > 1, "the first minibatch always takes one group"


def test_device_shares_of_a_tile_make_up_the_single_device_tile():
    # vmap with an axis name stands in for 4 devices: collectives and axis_index work the same way.
    key, num_envs, num_chunks, tile, devices = jax.random.key(3), 16, 4, (8, 2), 4
    env_index, chunk_index = minibatch_indices(key, num_envs, num_chunks, tile)
    shares, share_chunks = jax.vmap(
        lambda _: minibatch_indices(key, num_envs, num_chunks, tile, "devices"), axis_name="devices"
    )(jnp.arange(devices))
    assert shares.shape == (devices, 4, 2) and int(shares.max()) < num_envs // devices  # local indices
    local_to_global = shares + (np.arange(devices) * num_envs // devices)[:, None, None]
    np.testing.assert_array_equal(np.concatenate(list(local_to_global), axis=1), env_index)
    np.testing.assert_array_equal(share_chunks, np.broadcast_to(chunk_index, share_chunks.shape))


def test_tile_shape_prefers_the_most_trajectories():
    def tile(n, chunks, minibatch_chunks):
        return tile_shape(PPOConfig(num_envs=n, rollout_length=chunks * 16, minibatch_size=minibatch_chunks * 16))

    assert tile(8, 4, 8) == (8, 1)
    assert tile(6, 4, 8) == (2, 4)
    assert tile(16, 8, 4) == (4, 1)
    assert tile(5, 4, 8) is None


@pytest.mark.slow
def test_feed_forward_unroll_runs_the_chunk_as_one_batch_with_the_same_outputs_and_gradients():
    """A network without recurrent state skips the scan; its outputs and gradients are those of a step-by-step
    loop."""
    network = make_network(NetworkConfig(name="simple", width=8))
    model = ActorCritic(network, make_head("gaussian", ActionSpec(low=-jnp.ones(2), high=jnp.ones(2))))
    k1, k2, k3, k4 = jax.random.split(jax.random.key(1), 4)
    obs = Sensation.make(proprioception=jax.random.normal(k1, (T, B, 5)), asymmetric=jax.random.normal(k2, (T, B, 2)))
    params = model.init(k3, network.initial_carry(B), jax.tree.map(lambda x: x[0], obs))["params"]
    weights = jax.random.normal(k4, (T, B, model.head.num_params + 1))
    resets = jnp.zeros((T, B), bool).at[3].set(True)

    def batched(params):
        step = lambda c, o: model.apply({"params": params}, c, o)  # noqa: E731
        carry = network.initial_carry(B)
        _, policy, values = unroll(step, carry, carry, obs, resets)
        return (jnp.concatenate([policy, values[..., None]], -1) * weights).sum()

    def looped(params):
        outputs = []
        for t in range(T):
            _, policy, value = model.apply({"params": params}, network.initial_carry(B),
                                           jax.tree.map(lambda x, t=t: x[t], obs))
            outputs.append(jnp.concatenate([policy, value[:, None]], -1))
        return (jnp.stack(outputs) * weights).sum()

    jaxpr = str(jax.make_jaxpr(batched)(params))
    assert "scan" not in jaxpr and "while" not in jaxpr
    np.testing.assert_allclose(batched(params), looped(params), rtol=1e-5)
    for a, b in zip(jax.tree.leaves(jax.grad(batched)(params)), jax.tree.leaves(jax.grad(looped)(params)), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6)


def inner_jaxprs(eqn) -> list:
    """The jaxprs in an equation's parameters (a scan's body, a jit's program)."""
    found = []
    for param in eqn.params.values():
        for value in param if isinstance(param, tuple) else (param,):
            inner = getattr(value, "jaxpr", value)
            if hasattr(inner, "eqns"):
                found.append(inner)
    return found


def scans(jaxpr) -> list:
    """Every scan equation in `jaxpr`, nested programs searched (its body: `eqn.params["jaxpr"].jaxpr`)."""
    found = []
    for eqn in jaxpr.eqns:
        if eqn.primitive.name == "scan":
            found.append(eqn)
        else:
            for inner in inner_jaxprs(eqn):
                found.extend(scans(inner))
    return found


def matmuls(jaxpr) -> int:
    """dot_general equations in `jaxpr`, nested programs included."""
    return sum((eqn.primitive.name == "dot_general") + sum(matmuls(inner) for inner in inner_jaxprs(eqn))
               for eqn in jaxpr.eqns)


# network, its cell, the cells it scans, the matrix products of one cell's step (flax's GRU: three for the input,
# three for the state; its optimized LSTM: one for each), and whether the cells' scans are unrolled as on a GPU
@pytest.mark.slow
@pytest.mark.parametrize("name,cell,cells,products,gpu_unroll", [
    ("cortical", "gru", 1, 6, False), ("lstm", None, 2, 2, False), ("lstm", None, 2, 2, True),
    ("simple", None, 0, 0, False)], ids=["cortical-gru", "lstm", "lstm-unrolled-as-on-gpu", "simple"])
def test_networks_that_run_sequences_match_the_step_scan_with_only_their_cells_scanned(name, cell, cells, products,
                                                                                      gpu_unroll, monkeypatch):
    """Training runs a built-in network over a whole chunk (`runs_sequences`): dense layers on all s x B rows, only
    the recurrent cells scanned. Outputs, final carry and gradients equal those of the scan over whole steps, with
    the carry reset at episode starts, and the scanned body holds only the cell's matrix products. On a CPU the
    cells' scans loop step by step; on a GPU they unroll the whole chunk, which `gpu_unroll` runs here on the CPU."""
    from angora_jax.nets import models
    from angora_jax.nets.cortical import AREA_SIZES

    assert models.unrolled_steps(T) == 1, "a CPU loops"
    if gpu_unroll:
        monkeypatch.setattr(models, "unrolled_steps", lambda length: length)

    config = NetworkConfig(name=name, width=8, cell_size=8, cell=cell,
                           areas={area: 6 for area in AREA_SIZES} if name == "cortical" else {})
    network = make_network(config.validate())
    model = ActorCritic(network, make_head("gaussian", ActionSpec(low=-jnp.ones(2), high=jnp.ones(2))))
    assert model.runs_sequences
    keys = jax.random.split(jax.random.key(2), 6)
    obs = Sensation.make(proprioception=jax.random.normal(keys[0], (T, B, 5)),
                         touch=jax.random.normal(keys[1], (T, B, 3)), goal=jax.random.normal(keys[2], (T, B, 4)),
                         asymmetric=jax.random.normal(keys[3], (T, B, 2)))
    initial = network.initial_carry(B)
    params = model.init(keys[4], initial, jax.tree.map(lambda x: x[0], obs))["params"]
    start = jax.tree.map(lambda x: x + 0.3, initial)  # a stored carry from the rollout, not the episode start
    weights = jax.random.normal(keys[5], (T, B, model.head.num_params + 1))

    def loss(params, sequences):
        step = lambda c, o, *sequence: model.apply({"params": params}, c, o, *sequence)  # noqa: E731
        carry, policy, values = unroll(step, start, initial, obs, RESETS, sequences)
        return (jnp.concatenate([policy, values[..., None]], -1) * weights).sum(), carry

    (whole, carry), grads = jax.value_and_grad(loss, has_aux=True)(params, True)
    (stepped, stepped_carry), stepped_grads = jax.value_and_grad(loss, has_aux=True)(params, False)
    np.testing.assert_allclose(whole, stepped, rtol=1e-5)
    for a, b in zip(jax.tree.leaves((carry, grads)), jax.tree.leaves((stepped_carry, stepped_grads)), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6)
    cell_scans = scans(jax.make_jaxpr(lambda p: loss(p, True)[0])(params).jaxpr)
    bodies = [eqn.params["jaxpr"].jaxpr for eqn in cell_scans]
    stepped_scans = scans(jax.make_jaxpr(lambda p: loss(p, False)[0])(params).jaxpr)
    stepped_bodies = [eqn.params["jaxpr"].jaxpr for eqn in stepped_scans]
    assert len(bodies) == cells  # the plain LSTM's value pathway has a cell of its own
    assert [eqn.params["unroll"] for eqn in cell_scans] == [T if gpu_unroll else 1] * cells
    assert sum(matmuls(body) for body in bodies) == cells * products
    if cells:
        assert sum(matmuls(body) for body in stepped_bodies) > cells * products
