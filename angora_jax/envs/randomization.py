"""Domain randomization of the hand tasks: model fields scaled and an action delay drawn per environment at reset,
noise on actions and observations at every step.

`Randomization` holds the ranges of an env's `randomization` option (validated before anything compiles);
`ModelRandomizer` resolves them against a compiled model and draws, from a reset key, one environment's factors on
the model's fields. The draw is a pure JAX function of the key, so the MJX path (per-environment model fields set
with `mjx.Model.replace` inside the vmapped step: MJX's JAX implementation vmaps over them, MuJoCo Warp takes model
fields with a leading world axis) and the eager C MuJoCo twin (the same factors written into its own `MjModel`)
simulate the same worlds for the same key.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import sys

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from angora_jax.envs.core import Sensation

# Key of the drawn factors in an episode's `info`: they are held there for the whole episode.
INFO_KEY = "randomized_model"
# Key of the action delay's state in an episode's `info` (`ModelRandomizer.delay_state`).
DELAY_KEY = "delayed_control"
# Streams folded into the reset and step keys, so that randomization leaves the task's own draws as they were. The
# cube's size and the delay take streams of their own, so that adding them left the other ranges' draws unchanged.
_MODEL_STREAM, _ACTION_STREAM, _OBSERVATION_STREAM = 0x4D4F44, 0x414354, 0x4F4253
_SIZE_STREAM, _DELAY_STREAM = 0x53495A, 0x444C59
SCALES = ("friction", "joint_damping", "armature", "actuator_gain", "cube_mass", "cube_damping", "cube_size")
NOISES = ("action_noise", "observation_noise")
DELAYS = ("action_delay",)
CUBE_KEYS = ("cube_mass", "cube_damping", "cube_size")
# Scale ranges whose minimum must be > 0 (a cube without mass or size is no cube); the others' must be >= 0.
POSITIVE_SCALES = ("cube_mass", "cube_size")
# An action delay holds the controls of its last steps per environment: (delay, nu) floats each. More than about an
# episode (20 s at the hand's 0.02 s control step) is no delay a hand lives with, and only fills memory.
MAX_DELAY = 1000
# The cube's geom fields that its size scales: half sizes, bounding radius, bounding box (centre and half sizes).
CUBE_SIZE_FIELDS = ("geom_size", "geom_rbound", "geom_aabb")


@dataclasses.dataclass(frozen=True)
class Randomization:
    """Ranges of domain randomization; a scale range `(lo, hi)` multiplies the model's value by a factor drawn
    uniformly from it at every reset (None: not randomized). Noise is a standard deviation, drawn at every step.

    Attributes:
        friction: sliding friction of every geom, one factor per environment.
        joint_damping: damping of each hand joint, one factor per joint.
        armature: armature of each hand joint, one factor per joint.
        actuator_gain: each position actuator's stiffness kp (gain and bias together, so it still targets its control),
            one factor per actuator.
        cube_mass: the cube's mass and inertia (its density), one factor per environment.
        cube_damping: the damping of the cube's free joint, one factor per environment.
        cube_size: the cube's size s, one factor per environment: its geoms' half sizes, bounding radii and bounding
            boxes times s, its mass times s^3 and inertia times s^5 (the same density; with `cube_mass` both apply).
        action_delay: `(lo, hi)` policy steps, an integer k drawn uniformly per environment at reset: the physics
            receive the control of the action chosen k steps earlier (the first k steps of an episode hold the reset's
            control).
        action_noise: Gaussian noise added to each policy action component (action units, actions lie in [-1, 1]; the
            noisy action is clipped to the action bounds).
        observation_noise: Gaussian noise added to the proprioception and touch modalities, in their own units.
    """

    friction: tuple[float, float] | None = None
    joint_damping: tuple[float, float] | None = None
    armature: tuple[float, float] | None = None
    actuator_gain: tuple[float, float] | None = None
    cube_mass: tuple[float, float] | None = None
    cube_damping: tuple[float, float] | None = None
    cube_size: tuple[float, float] | None = None
    action_delay: tuple[int, int] | None = None
    action_noise: float = 0.0
    observation_noise: float = 0.0

    @classmethod
    def from_options(cls, options: dict | None, cube: bool) -> Randomization | None:
        """The ranges of an env's `randomization` option (None when it is absent); a ValueError naming the key
        and the fix for an unknown key, a key of the cube on a task without one (`cube` False), a range that is not
        `[lo, hi]` with `0 <= lo <= hi` (`0 < lo` for the cube's mass and size; integers for the delay) or a negative
        noise."""
        if options is None:
            return None
        if not isinstance(options, dict):
            raise ValueError(f"env.options.randomization must be a mapping of {SCALES + DELAYS + NOISES} to ranges, "
                             f"got {options!r}.")
        every = SCALES + DELAYS + NOISES
        known = every if cube else tuple(k for k in every if k not in CUBE_KEYS)
        for key in options:
            if key in CUBE_KEYS and not cube:
                raise ValueError(f"randomization.{key} applies to the cube task only; remove it for this task.")
            if key not in known:
                close = difflib.get_close_matches(str(key), known, n=1)
                raise ValueError(f"Unknown randomization key {key!r}{f' (did you mean {close[0]!r}?)' if close else ''}"
                                 f"; known: {list(known)}.")
        values = {}
        for key, value in options.items():
            name = f"randomization.{key}"
            if key in NOISES:
                if not isinstance(value, int | float) or not 0 <= value < math.inf:
                    raise ValueError(f"{name} is a standard deviation: give a finite number >= 0, got {value!r}.")
                values[key] = float(value)
                continue
            if key in DELAYS:
                if not isinstance(value, list | tuple) or len(value) != 2 or not all(
                        isinstance(v, int) and not isinstance(v, bool) for v in value):
                    raise ValueError(f"{name} is a range of policy steps: give integers [lo, hi], got {value!r}.")
                if not value[0] >= 0:
                    raise ValueError(f"{name} is a delay: its minimum must be >= 0, got {value[0]}.")
                if value[0] > value[1]:
                    raise ValueError(f"{name}'s minimum {value[0]} is above its maximum {value[1]}: give [lo, hi] "
                                     "with lo <= hi.")
                if value[1] > MAX_DELAY:
                    raise ValueError(f"{name}'s maximum must be <= {MAX_DELAY:,} policy steps, got {value[1]}.")
                values[key] = (int(value[0]), int(value[1]))
                continue
            if not isinstance(value, list | tuple) or len(value) != 2 or not all(
                    isinstance(v, int | float) and abs(v) <= sys.float_info.max for v in value):  # NaN fails too
                raise ValueError(f"{name} is a range of scale factors: give [lo, hi] of finite numbers, got {value!r}.")
            lo, hi = float(value[0]), float(value[1])
            if key in POSITIVE_SCALES and not lo > 0:
                raise ValueError(f"{name} scales the cube's {key.removeprefix('cube_')}: its minimum must be > 0, "
                                 f"got {lo}.")
            if not lo >= 0:
                raise ValueError(f"{name} scales a physical quantity: its minimum must be >= 0, got {lo}.")
            if lo > hi:
                raise ValueError(f"{name}'s minimum {lo} is above its maximum {hi}: give [lo, hi] with lo <= hi.")
            values[key] = (lo, hi)
        return cls(**values)


class ModelRandomizer:
    """`randomization` resolved against `model`: which fields and elements each range scales. `cube_body` names the
    cube's body (its free joint's dofs are the cube's, every other dof the hand's). `value_sees_physics`: the
    value function's `asymmetric` inputs also hold the episode's drawn physics (`physics_inputs`)."""

    def __init__(self, randomization: Randomization, model: mujoco.MjModel, cube_body: str | None = None,
                 value_sees_physics: bool = False):
        self.randomization = randomization
        self.model = model
        self.value_sees_physics = value_sees_physics
        cube_dofs = np.zeros(model.nv, bool)
        self.cube_body = -1
        if cube_body is not None:
            self.cube_body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, cube_body)
            cube_dofs = model.dof_bodyid == self.cube_body
        self.hand_dofs = np.flatnonzero(~cube_dofs)
        self.cube_dofs = np.flatnonzero(cube_dofs)
        self.cube_geoms = np.flatnonzero(model.geom_bodyid == self.cube_body) if cube_body is not None else None

    def draw(self, key: jax.Array) -> dict[str, jax.Array]:
        """One environment's factors drawn from a reset key: `MjModel` field name -> float32 array of the field's
        shape, by which `apply` and `write` multiply the model's value (1 where a field is not randomized). Factors
        rather than values, so that a range of zero width at 1 leaves each path's model exactly as it was (MJX's in
        float32, C MuJoCo's in float64). Pure JAX (jit, vmap)."""
        r, m = self.randomization, self.model
        # Every range takes its own key whether or not it is set, so one range's draw does not depend on the others.
        friction_key, damping_key, armature_key, gain_key, mass_key, cube_damping_key = jax.random.split(
            jax.random.fold_in(key, _MODEL_STREAM), 6)

        def factor(bounds: tuple[float, float], k: jax.Array, shape: tuple[int, ...] = ()) -> jax.Array:
            return jax.random.uniform(k, shape, jnp.float32, bounds[0], bounds[1])

        def ones(field: str) -> jax.Array:
            return jnp.ones(getattr(m, field).shape, jnp.float32)

        factors = {}
        if r.friction is not None:
            factors["geom_friction"] = ones("geom_friction").at[:, 0].set(factor(r.friction, friction_key))
        if r.joint_damping is not None or r.cube_damping is not None:
            damping = ones("dof_damping")
            if r.joint_damping is not None:
                damping = damping.at[self.hand_dofs].set(factor(r.joint_damping, damping_key, self.hand_dofs.shape))
            if r.cube_damping is not None:
                damping = damping.at[self.cube_dofs].set(factor(r.cube_damping, cube_damping_key))
            factors["dof_damping"] = damping
        if r.armature is not None:
            factors["dof_armature"] = ones("dof_armature").at[self.hand_dofs].set(
                factor(r.armature, armature_key, self.hand_dofs.shape))
        if r.actuator_gain is not None:
            # A position actuator's force is kp * ctrl - kp * length: gain and bias scale together.
            gain = factor(r.actuator_gain, gain_key, (m.nu,))
            factors["actuator_gainprm"] = ones("actuator_gainprm").at[:, 0].set(gain)
            factors["actuator_biasprm"] = ones("actuator_biasprm").at[:, 1].set(gain)
        if r.cube_mass is not None or r.cube_size is not None:
            mass = inertia = jnp.float32(1)
            if r.cube_mass is not None:
                density = factor(r.cube_mass, mass_key)
                mass, inertia = mass * density, inertia * density
            if r.cube_size is not None:
                # Mass grows with the volume (s^3), inertia with mass times length squared (s^5).
                size = factor(r.cube_size, jax.random.fold_in(key, _SIZE_STREAM))
                mass, inertia = mass * size**3, inertia * size**5
                for field in CUBE_SIZE_FIELDS:
                    factors[field] = ones(field).at[self.cube_geoms].set(size)
            factors["body_mass"] = ones("body_mass").at[self.cube_body].set(mass)
            factors["body_inertia"] = ones("body_inertia").at[self.cube_body].set(inertia)
        return factors

    def physics_inputs(self, factors: dict[str, jax.Array], delay: dict[str, jax.Array] | None) -> jax.Array:
        """An episode's drawn physics as inputs for the value function, `(P,)` float32: the log of each factor (0 where
        its field is not randomized, so the layout does not depend on which ranges are set), in the order friction
        (1), each hand joint's damping, then armature, each actuator's gain, and on the cube task its mass (with its
        size's s^3), free-joint damping and size (1 each); then the action delay in policy steps (0 without one).
        `factors`: `draw`'s; `delay`: `delay_state`'s, or None. Pure JAX."""
        def drawn(field: str, index) -> jax.Array:
            value = factors[field][index] if field in factors else jnp.ones(np.shape(getattr(self.model, field)[index]))
            return jnp.log(jnp.atleast_1d(value).astype(jnp.float32))

        parts = [drawn("geom_friction", (0, 0)), drawn("dof_damping", self.hand_dofs),
                 drawn("dof_armature", self.hand_dofs), drawn("actuator_gainprm", (slice(None), 0))]
        if self.cube_body >= 0:
            parts += [drawn("body_mass", self.cube_body), drawn("dof_damping", self.cube_dofs[0]),
                      drawn("geom_size", (self.cube_geoms[0], 0))]
        steps = jnp.zeros(1, jnp.float32) if delay is None else jnp.atleast_1d(delay["delay"]).astype(jnp.float32)
        return jnp.concatenate([*parts, steps])

    @property
    def delays(self) -> bool:
        """Whether actions are delayed: a delay range with a maximum above 0."""
        return self.randomization.action_delay is not None and self.randomization.action_delay[1] > 0

    def delay_state(self, key: jax.Array, control: jax.Array) -> dict[str, jax.Array]:
        """An episode's action delay, drawn from its reset key (pure JAX): `delay`, int32 policy steps, and `pending`,
        `(max delay, nu)` the controls of the last steps' actions, newest first, all `control` (the reset's) at the
        start."""
        lo, hi = self.randomization.action_delay
        delay = jax.random.randint(jax.random.fold_in(key, _DELAY_STREAM), (), lo, hi + 1, jnp.int32)
        return {"delay": delay, "pending": jnp.broadcast_to(control, (hi, *control.shape))}

    @staticmethod
    def delayed(control: jax.Array, state: dict[str, jax.Array]) -> tuple[jax.Array, dict[str, jax.Array]]:
        """The control the physics receive when this step's action asks for `control` `(nu,)`: the one asked for
        `delay` steps ago (this step's at delay 0), and the delay `state` with `control` taken in (pure JAX)."""
        queue = jnp.concatenate([control[None], state["pending"]])
        return queue[state["delay"]], {"delay": state["delay"], "pending": queue[:-1]}

    def apply(self, mjx_model, factors: dict[str, jax.Array]):
        """`mjx_model` (an `mjx.Model`) scaled by one environment's drawn `factors`; inside a vmapped step they carry
        the batch axis, which MJX's JAX implementation vmaps over and MuJoCo Warp reads as one world each."""
        # Factors have the `MjModel` field's shape, which MJX may lay out otherwise (`geom_aabb`: (ngeom, 2, 3)).
        return mjx_model.replace(**{name: getattr(mjx_model, name) * f.reshape(getattr(mjx_model, name).shape)
                                    for name, f in factors.items()})

    def write(self, model: mujoco.MjModel, factors: dict[str, jax.Array]) -> None:
        """Set C MuJoCo `model` (the eager twin's own copy) to `self.model` scaled by one environment's `factors`."""
        for name, f in factors.items():
            getattr(model, name)[:] = getattr(self.model, name) * np.asarray(f, np.float64)

    def noisy_action(self, action: jax.Array, key: jax.Array, low: jax.Array, high: jax.Array) -> jax.Array:
        """`action` `(nu,)` with `action_noise` added from a step key, clipped to `[low, high]` (unchanged when the
        noise is 0)."""
        std = self.randomization.action_noise
        if std == 0:
            return action
        noise = std * jax.random.normal(jax.random.fold_in(key, _ACTION_STREAM), action.shape, action.dtype)
        return jnp.clip(action + noise, low, high)

    def noisy_observation(self, obs: Sensation, key: jax.Array) -> Sensation:
        """`obs` with `observation_noise` added to proprioception and touch from a reset or step key (unchanged when
        the noise is 0)."""
        std = self.randomization.observation_noise
        if std == 0:
            return obs
        proprio_key, touch_key = jax.random.split(jax.random.fold_in(key, _OBSERVATION_STREAM))
        return obs.replace(
            proprioception=obs.proprioception + std * jax.random.normal(proprio_key, obs.proprioception.shape),
            touch=obs.touch + std * jax.random.normal(touch_key, obs.touch.shape))
