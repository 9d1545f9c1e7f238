"""Does MyoChallenge 2022's die rest in the MyoHand's palm, or fall, at rest and under random excitations?

The MyoHand with MyoSuite's die (`envs.myohand.die`: C MuJoCo, 2 ms) starts as MyoSuite's die task does (palm up,
the die above it, everything at rest) and is stepped for one episode of MyoSuite's die task (150 policy steps of
10 ms: 5 physics steps each) with no excitation, then with excitations drawn uniformly in [0, 1] per policy step.
Per run: how far the die's centre has moved at 0.1, 0.3, 0.75 and 1.5 s, and the first policy step at which it is
beyond MyoSuite's drop threshold (0.2 m). With --myosuite-xml the same runs go to MyoSuite's own die scene (its
legacy hand, the die on slide joints limited to +-25 cm); with --warp, MuJoCo Warp (on the CPU when there is no GPU)
steps our scene beside C MuJoCo for 20 policy steps of random excitations.

MyoSuite's scene, from its wheel (its meshes and scene come from myo-sim; its die texture is left out):

    pip download --no-deps myosuite==3.0.0 -d /tmp/myosuite && unzip -q /tmp/myosuite/*.whl -d /tmp/myosuite/src
    cd /tmp/myosuite/src/myosuite/envs/myo/assets && ln -s "$(python -c 'import myo_sim, os;
        print(os.path.dirname(myo_sim.__file__))')/models" myo_sim
    sed -e '/<texture name=.dice/d' -e '/<material name="MatDice"/d' -e 's/material="MatDice"//' \\
        hand/myohand_die.xml > hand/die_notex.xml

    python benchmarks/myohand_die.py --myosuite-xml /tmp/myosuite/src/myosuite/envs/myo/assets/hand/die_notex.xml --warp

Writes results/myohand/myohand_die_<platform>.json unless --out says otherwise.
"""

from __future__ import annotations

import argparse

import jax
import mujoco
import numpy as np
from common import markdown_table, write_results

from angora_jax.envs.mjx_env import local_device, mjx_module, quiet_iteration_caps, require_warp, warp_sizes
from angora_jax.envs.myohand.die import DIE, DIE_NCONMAX, DIE_NJMAX, DIE_POS, PALM_UP, die_start, load_hand_with_die
from angora_jax.envs.myohand.model import MYOHAND_PHYSICS

FRAME_SKIP = 5  # MyoSuite's die task: 10 ms policy steps
STEPS = 150  # its episode
DROP = 0.2  # its drop threshold (m)
TIMES = (0.1, 0.3, 0.75, 1.5)


def myosuite_scene(path: str) -> tuple[mujoco.MjModel, np.ndarray, int]:
    """MyoSuite's die scene, its start (`ReorientEnv`: hand joints 0, the forearm at -1.5 rad, the die's joints at 0)
    and the id of the die's centre site."""
    model = mujoco.MjModel.from_xml_path(path)
    qpos = model.qpos0.copy()
    qpos[:-7] = 0.0
    qpos[0] = PALM_UP
    return model, qpos, model.site("object_o").id


def our_scene() -> tuple[mujoco.MjModel, np.ndarray, int]:
    """Our die scene, its start and the die body's id (its centre is the body's `xpos`)."""
    model = load_hand_with_die()
    return model, die_start(model), model.body(DIE).id


def episode(model: mujoco.MjModel, qpos: np.ndarray, where, excitations: np.ndarray | None) -> dict:
    """One episode from `qpos`: the die's displacement (m) at `TIMES` and the first step beyond `DROP`."""
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    start = where(data).copy()
    moved = []
    for t in range(STEPS):
        data.ctrl[:] = 0.0 if excitations is None else excitations[t]
        mujoco.mj_step(model, data, nstep=FRAME_SKIP)
        moved.append(float(np.linalg.norm(where(data) - start)))
    dt = FRAME_SKIP * model.opt.timestep
    beyond = [t + 1 for t, m in enumerate(moved) if m > DROP]
    row = {f"moved_{s}s_m": moved[round(s / dt) - 1] for s in TIMES}
    return row | {"first_step_beyond_drop": beyond[0] if beyond else None}


def warp_agreement(seed: int) -> dict:
    """Our scene on MuJoCo Warp and C MuJoCo, 20 policy steps of random excitations: the largest difference of the
    die's position (m) and of the hand's joint angles (rad)."""
    require_warp()
    model = load_hand_with_die(MYOHAND_PHYSICS.with_options({"impl": "warp"}))
    data = mujoco.MjData(model)
    data.qpos[:] = die_start(model)
    mujoco.mj_forward(model, data)
    device = local_device("warp")
    mjx = mjx_module()
    mjx_model = quiet_iteration_caps(mjx.put_model(model, device=device, impl="warp"))
    state = mjx.put_data(model, data, device=device, impl="warp", **warp_sizes(model, 1))  # the scene's budget

    @jax.jit
    def policy_step(state, ctrl):
        return jax.lax.fori_loop(0, FRAME_SKIP, lambda _, s: mjx.step(mjx_model, s), state.replace(ctrl=ctrl))

    die, joints = model.body(DIE).id, model.joint(DIE).qposadr[0]  # the hand's joints come before the die's
    worst_die = worst_joint = 0.0
    for ctrl in np.random.default_rng(seed).uniform(0.0, 1.0, (20, model.nu)):
        state = policy_step(state, ctrl.astype(np.float32))
        data.ctrl[:] = ctrl
        mujoco.mj_step(model, data, nstep=FRAME_SKIP)
        worst_die = max(worst_die, float(np.abs(np.asarray(state.xpos[die]) - data.xpos[die]).max()))
        worst_joint = max(worst_joint, float(np.abs(np.asarray(state.qpos[:joints]) - data.qpos[:joints]).max()))
    return {"scene": "ours", "physics": "Warp against C MuJoCo", "policy_steps": 20, "die_position_error_m": worst_die,
            "joint_angle_error_rad": worst_joint}


def main(argv: list[str] | None = None) -> int:
    """Run the episodes with command-line `argv` (default: sys.argv); write the JSON and print a table."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=3, help="episodes of random excitations per scene")
    parser.add_argument("--myosuite-xml", default=None, help="MyoSuite's die scene (see above), compared beside ours")
    parser.add_argument("--warp", action="store_true", help="also check MuJoCo Warp against C MuJoCo on our scene")
    parser.add_argument("--out", default=None, help="JSON path (default: results/myohand/myohand_die_<platform>)")
    args = parser.parse_args(argv)
    scenes = {"ours": our_scene()}
    if args.myosuite_xml:
        scenes["myosuite"] = myosuite_scene(args.myosuite_xml)
    rows = []
    for name, (model, qpos, handle) in scenes.items():
        where = (lambda d, h=handle: d.site_xpos[h]) if name == "myosuite" else (lambda d, h=handle: d.xpos[h])
        rows.append({"scene": name, "excitation": "none", "seed": None} | episode(model, qpos, where, None))
        for seed in range(args.seeds):
            excitations = np.random.default_rng(seed).uniform(0.0, 1.0, (STEPS, model.nu))
            rows.append({"scene": name, "excitation": "random", "seed": seed}
                        | episode(model, qpos, where, excitations))
    columns = [("scene", "scene", "s"), ("excitation", "excitation", "s"), ("seed", "seed", "d")]
    columns += [(f"moved_{s}s_m", f"moved at {s} s (m)", ".3f") for s in TIMES]
    columns += [("first_step_beyond_drop", "first 10 ms step beyond 0.2 m", "d")]
    print(markdown_table(rows, columns))
    if args.warp:
        rows.append(warp_agreement(0))
        print(rows[-1])
    config = {"frame_skip": FRAME_SKIP, "steps": STEPS, "drop_m": DROP, "die_pos": DIE_POS, "seeds": args.seeds,
              "myosuite_xml": args.myosuite_xml,
              "warp_sizes": {"nconmax": DIE_NCONMAX, "njmax": DIE_NJMAX} if args.warp else None}
    print(f"wrote {write_results('myohand_die', config, rows, args.out, study='myohand')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
