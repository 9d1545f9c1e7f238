"""What to probe of the brain-area model (`cortical`) on each hand task: the areas, the variables to decode, the
lesions, the outcomes that measure them and the model variables of RSA (`PROBES`, keyed by task name). One list for
benchmarks/probe_trained.py and the example notebooks, so that the benchmark's numbers and the tutorials probe the same
things.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import mujoco

from angora_jax.analysis.lesion import lesion, lesion_area, lesion_fraction, silence_actions, silence_modality
from angora_jax.experiment.agent import Agent


@dataclass(frozen=True)
class Probe:
    """What to probe on a task: the `layers` to decode from and analyse (recorded layer names, e.g. `network.PMC.1`),
    the `variables` to decode (recorded variable names, e.g. `task_fingertips`), the `lesions` (a function of the
    agent giving name -> lesioned agent, for `ablation`), the episode `outcomes` to compare them by (the first is the
    one to plot), and the model variables of RSA (`rsa_variables`; none: no RSA), whose conditions are bins of
    `rsa_condition`."""

    layers: tuple[str, ...]
    variables: tuple[str, ...]
    lesions: Callable[[Agent], dict[str, Agent]]
    outcomes: tuple[str, ...]
    rsa_variables: tuple[str, ...] = ()
    rsa_condition: str = "metric_goal_distance"


def reach_lesions(agent: Agent) -> dict[str, Agent]:
    """Reach's lesions of `agent` (name -> lesioned agent): SSC_2, IPS, MCC, half and a tenth of M1, the goal and
    proprioceptive inputs, and the empty lesion (no unit; it must equal the intact agent)."""
    return {"-SSC_2": lesion_area(agent, "network.SSC_2"), "-IPS": lesion_area(agent, "network.IPS"),
            "-MCC": lesion_area(agent, "network.MCC"), "-50% M1": lesion_fraction(agent, "network.M1", 0.5),
            "-10% M1": lesion_fraction(agent, "network.M1", 0.1),
            "-goal input": silence_modality(agent, "goal"),
            "-proprioception": silence_modality(agent, "proprioception"),
            "-none": lesion(agent, "network.M1", [])}


def cube_lesions(agent: Agent) -> dict[str, Agent]:
    """The cube's lesions of `agent` (name -> lesioned agent): SSC (both SSC_1 and SSC_2), the touch and goal inputs,
    a tenth and half of M1, and the empty lesion (no unit; it must equal the intact agent)."""
    return {"-SSC": lesion_area(lesion_area(agent, "network.SSC_1"), "network.SSC_2"),
            "-touch input": silence_modality(agent, "touch"),
            "-goal input": silence_modality(agent, "goal"),
            "-10% M1": lesion_fraction(agent, "network.M1", 0.1),
            "-50% M1": lesion_fraction(agent, "network.M1", 0.5),
            "-none": lesion(agent, "network.M1", [])}


def muscle_lesions(agent: Agent) -> dict[str, Agent]:
    """A muscle-driven hand's lesions of `agent` (name -> lesioned agent): each muscle silenced on its own (its
    excitation held at 0, `silence_actions`; named `-<actuator name>`), M1 and the muscle sense, and the empty lesion
    (no muscle; it must equal the intact agent). The silenced muscle is data of the compiled programs: the muscles'
    lesions and the intact agent share one evaluation program."""
    model = agent.env.task.model
    muscles = {f"-{mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, i)}": silence_actions(agent, [i])
               for i in range(model.nu)}
    return {**muscles, "-M1": lesion_area(agent, "network.M1"), "-muscle sense": silence_modality(agent, "muscle"),
            "-none": silence_actions(agent, [])}


PROBES = {
    "ShadowHandReach": Probe(
        layers=("network.SSC_2", "network.SPL", "network.IPS", "network.MCC", "network.LPFC", "network.PMC.1",
                "network.M1"),
        variables=("input_goal", "input_asymmetric", "input_proprioception", "metric_goal_distance"),
        lesions=reach_lesions, outcomes=("success", "goal_distance")),
    # The cube's variables (Env.task_variables): its orientation (rotation matrix: sign-free, unlike the quaternion),
    # angular velocity (rad/s, cube frame), the rotation from it to the goal (rotation matrix), the fingertips (m) and
    # the touch sensors (N).
    "ShadowHandCube": Probe(
        layers=("network.SSC_1", "network.SSC_2", "network.SPL", "network.IPL", "network.IPS", "network.MCC",
                "network.LPFC", "network.PMC_in", "network.PMC.1", "network.M1"),
        variables=("task_cube_rotation", "task_cube_angular_velocity", "task_rotation_to_goal", "task_fingertips",
                   "input_touch"),
        lesions=cube_lesions, outcomes=("goals_reached", "dropped"),
        rsa_variables=("task_cube_rotation", "task_rotation_to_goal", "task_cube_angular_velocity")),
    # The muscle hand's variables (MuscleHandTask.task_variables): what the muscles do (forces in N, activations and
    # the excitations sent, in [0, 1]) and what the joints do (angles in rad, velocities in rad/s), the
    # muscles-or-movements question's two sides; the target posture and the pose error (the outcome).
    "MyoHandPose": Probe(
        layers=("network.SSC_1", "network.SSC_2", "network.SPL", "network.IPL", "network.IPS", "network.MCC",
                "network.LPFC", "network.PMC_in", "network.PMC.1", "network.M1"),
        variables=("task_muscle_force", "task_muscle_activation", "task_joint_angles", "task_joint_velocities",
                   "task_target", "metric_pose_error"),
        lesions=muscle_lesions, outcomes=("pose_error", "success"),
        rsa_variables=("task_target", "task_joint_angles", "task_muscle_activation"),
        rsa_condition="metric_pose_error"),
}
