"""Networks: every registered model on hand-like and minimal inputs, the asymmetric-input rule, options, a custom
module through the compiled cycle."""

from dataclasses import replace

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from angora_jax.envs.classic import CartPole
from angora_jax.envs.core import ActionSpec, Sensation
from angora_jax.experiment.config import load_config
from angora_jax.nets import ActorCritic, list_networks, make_network, register_network
from angora_jax.nets.activations import lif, lif_fraction
from angora_jax.nets.area_graph import evaluation_order, feedback_inputs
from angora_jax.nets.components import save_component, stop_frozen_gradients
from angora_jax.nets.cortical import AREA_SIZES
from angora_jax.ppo import NetworkConfig, NormalizationConfig, PPOConfig, make_cycle, make_head
from angora_jax.ppo.tbptt import unroll

BATCH = 3
HEAD = make_head("gaussian", ActionSpec(low=-jnp.ones(20), high=jnp.ones(20)))


def hand_like_obs(key: jax.Array, asymmetric_scale: float = 1.0) -> Sensation:
    """Shaped like Shadow-hand reach: proprioception and goal, privileged fingertips, no touch or vision."""
    k1, k2, k3 = jax.random.split(key, 3)
    return Sensation.make(
        proprioception=jax.random.normal(k1, (BATCH, 48)),
        goal=jax.random.normal(k2, (BATCH, 15)),
        asymmetric=asymmetric_scale * jax.random.normal(k3, (BATCH, 15)),
    )


def small(name: str, shared: bool = False) -> NetworkConfig:
    return NetworkConfig(name=name, width=16, cell_size=16, shared_trunk=shared)


def test_registry_has_the_required_models():
    assert {"simple", "deeper", "rnn", "lstm", "gru", "wide", "cortical", "areas"} <= set(list_networks())
    with pytest.raises(ValueError, match="Unknown network 'nope'"):
        make_network(NetworkConfig(name="nope"))


@pytest.mark.parametrize("shared", [False, True], ids=["separate", "shared"])
# The brain-area model compiles in 11 s; `make test-fast` checks its areas and its graph below.
@pytest.mark.parametrize("name", ["simple", "deeper", "rnn", "lstm", "gru", "wide",
                                  pytest.param("cortical", marks=pytest.mark.slow)])
def test_network_contract_shapes_and_asymmetric_reaches_only_the_value(name, shared):
    model = ActorCritic(make_network(small(name, shared)), HEAD)
    obs = hand_like_obs(jax.random.key(0))
    carry = model.network.initial_carry(BATCH)
    params = model.init(jax.random.key(1), carry, obs)
    new_carry, policy_params, value = model.apply(params, carry, obs)
    assert policy_params.shape == (BATCH, HEAD.num_params)
    assert value.shape == (BATCH,)
    assert jax.tree.map(jnp.shape, new_carry) == jax.tree.map(jnp.shape, carry)
    assert all(leaf.shape[0] == BATCH for leaf in jax.tree.leaves(carry))

    other = obs.replace(asymmetric=obs.asymmetric + 5.0)
    _, other_policy, other_value = model.apply(params, carry, other)
    np.testing.assert_array_equal(policy_params, other_policy)
    assert not np.allclose(value, other_value)


def test_shared_trunk_has_fewer_parameters_than_separate_trunks():
    obs = hand_like_obs(jax.random.key(0))

    def count(shared):
        network = make_network(small("lstm", shared))
        params = ActorCritic(network, HEAD).init(jax.random.key(0), network.initial_carry(BATCH), obs)
        return sum(leaf.size for leaf in jax.tree.leaves(params))

    assert count(True) < count(False)


def test_recurrent_carry_carries_memory_and_feed_forward_carry_is_empty():
    obs = hand_like_obs(jax.random.key(0))
    for name, remembers in [("simple", False), ("gru", True)]:
        model = ActorCritic(make_network(small(name)), HEAD)
        carry = model.network.initial_carry(BATCH)
        params = model.init(jax.random.key(1), carry, obs)
        carry_after, first, _ = model.apply(params, carry, obs)
        _, second, _ = model.apply(params, carry_after, obs)
        assert (not np.allclose(first, second)) == remembers, name
    assert make_network(small("simple")).initial_carry(4).shape == (4, 0)


def test_modalities_enter_separately():
    network = make_network(small("lstm"))
    params = ActorCritic(network, HEAD).init(
        jax.random.key(0), network.initial_carry(BATCH), hand_like_obs(jax.random.key(0))
    )
    encoder = params["params"]["network"]["policy_encoder"]
    assert set(encoder) == {"embed_proprioception", "embed_goal"}  # empty touch and vision get no layer


def test_cortical_areas_are_named_sized_and_recurrent():
    """Shapes only, so traced (`jax.eval_shape`): 1 s of CPU instead of 11 run op by op. The cortical model is run
    in test_the_shipped_cortical_graph_is_the_builtin_cortical_model."""
    obs = hand_like_obs(jax.random.key(0))
    for cell, carry_shapes in [("rnn", (BATCH, 16)), ("lstm", ((BATCH, 16), (BATCH, 16))), ("gru", (BATCH, 16))]:
        network = make_network(NetworkConfig(name="cortical", cell=cell, cell_size=16, width=8, areas={"M1": 24}))
        params = jax.eval_shape(network.init, jax.random.key(0), network.initial_carry(BATCH), obs)["params"]
        assert set(AREA_SIZES) <= set(params) and params["M1"]["kernel"].shape[-1] == 24
        assert params["SSC_1"]["kernel"].shape == (48, 128), "SSC reads proprioception (and touch, empty here)"
        assert params["MCC"]["kernel"].shape == (15 + 64, 64), "MCC reads the goal and SSC"
        carry, features, _ = jax.eval_shape(network.apply, {"params": params}, network.initial_carry(BATCH), obs)
        assert jax.tree.map(jnp.shape, carry) == {"PMC": carry_shapes} and features.shape == (BATCH, 24)
    for bad, match in [({"areas": {"V9": 3}}, "Unknown areas \\['V9'\\]"), ({"cell": "lstm2"}, "network.cell must be"),
                       ({"name": "simple", "cell": "gru"}, "network.cell applies to the wide and cortical networks")]:
        with pytest.raises(ValueError, match=match):
            PPOConfig(network=NetworkConfig(**{"name": "cortical"} | bad)).validate()


def test_the_wide_network_takes_any_cell_and_rnn_is_a_plain_network():
    obs = hand_like_obs(jax.random.key(0))
    for config, cell_params in [(NetworkConfig(name="wide", cell="rnn", width=8, cell_size=8), {"i", "h"}),
                                (NetworkConfig(name="wide", cell="gru", width=8, cell_size=8), {"ir", "iz", "in"}),
                                (small("rnn"), {"i", "h"})]:
        network = make_network(config.validate())
        params = network.init(jax.random.key(0), network.initial_carry(BATCH), obs)["params"]
        assert cell_params <= set(params["policy_cell"]), (config, sorted(params["policy_cell"]))


def tiny_sizes(config: str) -> list[str]:
    """Overrides that shrink every area of a shipped graph config (4 units and up, each area a different size, so
    that a size given to the wrong area shows) and its value net."""
    areas = load_config(config).ppo.network.graph.areas
    return [*(f"ppo.network.graph.areas.{name}.size={4 + i}" for i, name in enumerate(areas)),
            "ppo.network.graph.value.sizes=[6, 6]"]


def every_modality(key: jax.Array, batch: int = BATCH) -> Sensation:
    """Every modality present (none empty), random, `(batch, size)`: each kernel row of every input is used."""
    sizes = {"proprioception": 7, "touch": 3, "muscle": 5, "vision": 4, "goal": 2, "asymmetric": 3}
    keys = jax.random.split(key, len(sizes))
    return Sensation.make(**{name: jax.random.normal(k, (batch, size))
                             for k, (name, size) in zip(keys, sizes.items(), strict=True)})


def test_the_shipped_cortical_graph_is_the_builtin_cortical_model(quick_compiles):
    """shadow_reach_cortical_graph (an `areas` graph in YAML) and shadow_reach_cortical (the built-in `cortical`) at
    the same sizes: the same graph, so for one seed the same parameters and, from the same carry, the same outputs.
    The models are the programs' static arguments: equal models compile once."""
    graph = load_config("shadow_reach_cortical_graph", tiny_sizes("shadow_reach_cortical_graph")).ppo.network
    sizes = {name: spec.size for name, spec in graph.graph.areas.items()}
    builtin = load_config("shadow_reach_cortical", [f"ppo.network.areas={sizes}", "ppo.network.width=6"]).ppo.network
    yaml_model, builtin_model = make_network(graph.validate()), make_network(builtin.validate())
    assert yaml_model.graph == builtin_model.graph
    obs = every_modality(jax.random.key(0))
    carry = jax.tree.map(lambda x: jax.random.normal(jax.random.key(1), x.shape), builtin_model.initial_carry(BATCH))
    init = jax.jit(lambda model, key: model.init(key, carry, obs), static_argnums=0)
    apply = jax.jit(lambda model, params: model.apply(params, carry, obs), static_argnums=0)
    outputs = []
    for model in (yaml_model, builtin_model):
        params = init(model, jax.random.key(2))
        outputs.append((params, apply(model, params)))
    assert jax.tree.structure(outputs[0]) == jax.tree.structure(outputs[1])
    for mine, builtin_leaf in zip(jax.tree.leaves(outputs[0]), jax.tree.leaves(outputs[1]), strict=True):
        np.testing.assert_array_equal(mine, builtin_leaf)
    assert outputs[0][0]["params"]["value_net"]["Dense_1"]["kernel"].shape == (6, 6)


@pytest.mark.slow
def test_a_shipped_graph_with_feedback_and_lif_unrolls_and_resets(quick_compiles):
    """AngoraPy's shadowv2 wiring (shipped), tiny, with M1 firing as LiF units and a feedback input (LPFC reads the
    premotor cell, which reads LPFC): LPFC takes PMC's previous output. Over a sequence an environment whose episode
    restarts acts as a fresh one; one that goes on remembers; the policy never sees `asymmetric`."""
    overrides = [*tiny_sizes("shadow_reach_shadowv2"), "ppo.network.graph.areas.M1.activation=lif",
                 "ppo.network.graph.areas.LPFC.inputs=[MCC, IPL, IPS, PMC]"]
    config = load_config("shadow_reach_shadowv2", overrides).ppo.network.validate()
    network = make_network(config)
    assert feedback_inputs(network.graph) == {("LPFC", "PMC")}
    assert evaluation_order(network.graph).index("LPFC") < evaluation_order(network.graph).index("PMC")
    model = ActorCritic(network, HEAD)
    steps = 4
    obs = jax.tree.map(lambda x: x.reshape(steps, BATCH, -1), every_modality(jax.random.key(0), steps * BATCH))
    initial = network.initial_carry(BATCH)
    params = jax.jit(model.init)(jax.random.key(1), initial, jax.tree.map(lambda x: x[0], obs))

    @jax.jit
    def run(sequence, resets):
        return unroll(lambda carry, o: model.apply(params, carry, o), initial, initial, sequence, resets)[1:]

    resets = jnp.zeros((steps, BATCH)).at[2, 0].set(1.0)
    policy, value = run(obs, resets)
    # The last two steps first, from the initial carry (twice over: one sequence length, one compiled program).
    fresh, _ = run(jax.tree.map(lambda x: jnp.concatenate([x[2:], x[2:]]), obs), jnp.zeros((steps, BATCH)))
    np.testing.assert_allclose(policy[2:, 0], fresh[:2, 0], rtol=1e-6, atol=1e-6)
    assert not np.allclose(policy[2:, 1], fresh[:2, 1]), "without a reset the carry remembers the first steps"
    other = obs.replace(asymmetric=obs.asymmetric + 5.0)
    other_policy, other_value = run(other, resets)
    np.testing.assert_array_equal(policy, other_policy)
    assert not np.allclose(value, other_value)


def test_lif_is_angorapys_soft_leaky_integrate_and_fire_rate():
    x = jnp.array([-100.0, 0.0, 1.0, 1000.0])
    np.testing.assert_allclose(lif(x), [0.005, 9.655, 55.98, 248.76], rtol=2e-3)
    assert np.all(np.isfinite(jax.vmap(jax.grad(lif))(x))), "no NaN gradient below the threshold"
    np.testing.assert_allclose(lif_fraction(x), lif(x) / 250.0, rtol=1e-6)


@pytest.mark.slow
def test_frozen_component_keeps_its_pretrained_values_through_updates(tmp_path, quick_compiles):
    areas = {name: 8 for name in AREA_SIZES}
    network = NetworkConfig(name="cortical", cell="gru", width=8, areas=areas)
    config = PPOConfig(num_envs=4, rollout_length=16, chunk_length=8, minibatch_size=32, num_epochs=2,
                       network=network)
    env = CartPole()
    donor = make_cycle(env, None, config)[0](jax.random.key(7)).params
    file = save_component(donor, "network.SSC_1", tmp_path / "ssc.msgpack")
    with pytest.raises(FileExistsError, match="never overwritten"):
        save_component(donor, "network.SSC_1", file)
    frozen = config.replace(network=replace(network, pretrained={"network.SSC_1": str(file)},
                                            frozen=("network.SSC_1",)))
    init, cycle = make_cycle(env, None, frozen)
    state = init(jax.random.key(0))
    np.testing.assert_array_equal(state.params["network"]["SSC_1"]["kernel"], donor["network"]["SSC_1"]["kernel"])
    after, _ = cycle(state)
    for name in ("kernel", "bias"):
        np.testing.assert_array_equal(after.params["network"]["SSC_1"][name], donor["network"]["SSC_1"][name])
    assert not np.array_equal(after.params["network"]["M1"]["kernel"], state.params["network"]["M1"]["kernel"])
    with pytest.raises(ValueError, match="No module 'network.S1'.*network.SSC_1"):
        make_cycle(env, None, config.replace(network=replace(network, frozen=("network.S1",))))[0](jax.random.key(0))


def test_a_frozen_area_gets_no_gradient_and_no_backward_pass():
    """A frozen first layer: its kernel's gradient is zero and the gradient program drops the backward pass through
    it (3 matrix products: two forward, one for the second kernel; 5 when both layers train)."""
    params = {"visual": {"kernel": jnp.ones((6, 5))}, "network": {"kernel": jnp.ones((5, 2))}}
    images = jnp.ones((4, 6))

    def loss(params, frozen):
        params = stop_frozen_gradients(params, frozen)
        return jnp.sum(jnp.tanh(images @ params["visual"]["kernel"]) @ params["network"]["kernel"])

    def products(frozen):
        jaxpr = jax.make_jaxpr(jax.grad(lambda p: loss(p, frozen)))(params)
        return str(jaxpr).count("dot_general")

    grads = jax.grad(loss)(params, ("visual",))
    assert np.all(grads["visual"]["kernel"] == 0) and np.all(grads["network"]["kernel"] != 0)
    assert (products(("visual",)), products(())) == (3, 5)
    assert stop_frozen_gradients(params, ()) is params
    with pytest.raises(ValueError, match="visul"):
        stop_frozen_gradients(params, ("visul",))


class TinyUserNet(nn.Module):
    """A user-written module following the contract: a GRU over proprioception only."""

    def initial_carry(self, batch_size):
        return jnp.zeros((batch_size, 8))

    @nn.compact
    def __call__(self, carry, obs):
        carry, features = nn.GRUCell(8)(carry, obs.proprioception)
        return carry, features, nn.Dense(1)(features)[..., 0]


@pytest.mark.slow
def test_user_module_and_registered_builder_run_in_the_compiled_cycle(quick_compiles):
    register_network("test_tiny_user_net", lambda config: TinyUserNet())
    config = PPOConfig(
        num_envs=4,
        rollout_length=16,
        chunk_length=8,
        minibatch_size=32,
        num_epochs=1,
        network=NetworkConfig(name="test_tiny_user_net"),
        normalization=NormalizationConfig(observations=False, rewards=False),
    )
    init, cycle = make_cycle(CartPole(), None, config)
    start = init(jax.random.key(0))
    state, metrics = cycle(start)
    assert state.actor.carry.shape == (4, 8)
    assert float(metrics["finite"]) == 1.0
    assert int(state.cycle) == 1
    # Normalisation switched off: its state is left alone.
    for before, after in zip(
        jax.tree.leaves((start.obs_stats, start.reward_stats)),
        jax.tree.leaves((state.obs_stats, state.reward_stats)),
        strict=True,
    ):
        np.testing.assert_array_equal(before, after)
