"""`MuscleHandTask`: what every MyoHand task shares, whatever its goal: actions as muscle excitations, the muscle
modality (the muscle sense and an efference copy of the activations), the effort cost and MyoSuite's success rule over
an episode's solved steps."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from angora_jax.envs.mujoco_task import MujocoTask, Snapshot

# MyoSuite's success rule (`evaluate_success`, `successful_steps=5`): solved on more than this many steps.
SUCCESS_STEPS = 5


class MuscleHandTask(MujocoTask):
    """A task on a model driven only by muscles (MuJoCo muscle dynamics, one activation each).

    Actions are the muscles' excitations in [0, 1], written to `ctrl`; values outside are clipped, as MuJoCo clamps the
    muscles' limited `ctrl` and MyoSuite clips actions to its action space. Activations follow the excitations with
    MuJoCo's activation dynamics, from 0 at an episode's start (no excitation then). Subclasses draw the goal, observe
    and judge; they call `count_success` with each step's `solved`, charge `effort`, and keep the goal in
    `info["target"]`, which `task_variables` reports.

    Attributes:
        model: the compiled hand.
        success_steps: an episode is a success when solved on more than this many steps.
    """

    muscle_sense = True

    def __init__(self, model: mujoco.MjModel, success_steps: int = SUCCESS_STEPS):
        name = type(self).__name__
        if model.nu != model.na or not np.all(model.actuator_dyntype == mujoco.mjtDyn.mjDYN_MUSCLE):
            raise ValueError(f"{name} drives muscles: every actuator must have muscle dynamics (one activation "
                             f"each), got nu={model.nu}, na={model.na}.")
        if isinstance(success_steps, bool) or not isinstance(success_steps, int) or success_steps < 0:
            raise ValueError(f"success_steps must be a whole number >= 0, got {success_steps!r}.")
        self.model = model
        self.success_steps = success_steps
        self._ctrl_low, self._ctrl_high = model.actuator_ctrlrange.T.astype(np.float32)

    def initial_control(self, snap: Snapshot) -> jax.Array:
        """No excitation: every muscle at rest."""
        return jnp.zeros(self.model.nu, jnp.float32)

    def action_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The muscles' excitation range, [0, 1] each."""
        return self._ctrl_low, self._ctrl_high

    def control(self, action: jax.Array, snap: Snapshot) -> jax.Array:
        return jnp.clip(action, self._ctrl_low, self._ctrl_high)

    def muscles(self, snap: Snapshot) -> jax.Array:
        """The muscle modality `(4 * nu,)`, each block in actuator order: lengths (m), lengthening velocities (m/s),
        forces (N, negative when pulling), then activations (dimensionless, in [0, 1], MuJoCo's `act`).

        The first three are what muscle spindles and Golgi tendon organs sense. The activations are no receptor's
        sense but an efference copy: the motor command's own state, which MyoSuite's pose task observes too
        (`act` in its observation) and which a feed-forward policy otherwise could not know, since activations lag
        the excitations by MuJoCo's activation dynamics (10-40 ms)."""
        return jnp.concatenate([snap.actuator_length, snap.actuator_velocity, snap.actuator_force, snap.act])

    def effort(self, snap: Snapshot) -> jax.Array:
        """The effort cost: the mean squared activation over the muscles (MyoSuite's generic `act_reg` term)."""
        return jnp.mean(snap.act ** 2)

    def count_success(self, solved_steps: jax.Array, solved: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The episode's solved steps after a step that is `solved` (bool), and its success so far (1.0 when solved on
        more than `success_steps` steps; its value at an episode's end is MyoSuite's success)."""
        solved_steps = solved_steps + solved.astype(jnp.int32)
        return solved_steps, (solved_steps > self.success_steps).astype(jnp.float32)

    def task_variables(self, snap: Snapshot, info: dict[str, jax.Array]) -> dict[str, jax.Array]:
        """joint_angles (23, rad), joint_velocities (23, rad/s), target (the task's goal, `info["target"]`),
        muscle_force (39, N), muscle_activation (39, in [0, 1]) and muscle_excitation (39, the `ctrl` the last action
        set, in [0, 1]): what the muscles-or-movements analyses decode from a network's layers, the synergies factorise
        and a muscle's lesion silences."""
        return {"joint_angles": snap.qpos, "joint_velocities": snap.qvel, "target": info["target"],
                "muscle_force": snap.actuator_force, "muscle_activation": snap.act, "muscle_excitation": snap.ctrl}

    def task_variable_labels(self) -> dict[str, tuple[str, ...]]:
        """The muscles' names (the model's actuators in order, e.g. `FPL_r`; `actuator i` for an unnamed one) for the
        muscle variables: action i is muscle i's excitation, so they name the actions too."""
        muscles = tuple(mujoco.mj_id2name(self.model, mujoco.mjtObj.mjOBJ_ACTUATOR, i) or f"actuator {i}"
                        for i in range(self.model.nu))
        return {"muscle_force": muscles, "muscle_activation": muscles, "muscle_excitation": muscles}
