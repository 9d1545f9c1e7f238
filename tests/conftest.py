"""Test-wide settings."""

import atexit
import json
import os
import shutil
import tempfile
import time
from types import SimpleNamespace

# Headless rendering: MuJoCo's default GLFW backend needs a display; EGL (Mesa's on CPUs) does not.
os.environ.setdefault("MUJOCO_GL", "egl")

# Single-threaded Eigen, for the tests and the subprocesses they start. It was set against a deadlock on 2 cores (every
# thread idle, forever, when MJX factored 44 or more hand environments' mass matrices) that it does not prevent: the
# cause is jaxlib's batched LAPACK waiting inside XLA's CPU pool, and angora_jax/cpu_threads.py sizes that pool so
# that it cannot happen. It stays because the suite's timings (benchmarks/results/suite_profile) were measured with it.
if "xla_cpu_multi_thread_eigen" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} --xla_cpu_multi_thread_eigen=false".strip()

# Many tests train the same tiny configs, and each run builds its cycle afresh, so XLA compiles identical programs
# again and again. JAX's persistent compilation cache, in a folder of this session only (nothing carries over between
# sessions, so no test depends on an earlier one), turns the repeats into cache reads. Subprocesses inherit it.
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
    os.environ["JAX_COMPILATION_CACHE_DIR"] = tempfile.mkdtemp(prefix="angora_jax_xla_cache_")
    atexit.register(shutil.rmtree, os.environ["JAX_COMPILATION_CACHE_DIR"], ignore_errors=True)
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")


import pytest  # noqa: E402  (after the environment above, which must be set before JAX starts)

# The order in which `make test`'s two workers take the test files (pytest-xdist gives each file to one worker, the
# next file to whichever worker runs out first; `--no-loadscope-reorder` keeps this order): the longest first, so that
# the last files to start are short and both workers end together. test_evaluation comes first because it trains
# the shared cortical reach run (`cortical_reach` below, about 3 minutes in the suite), and the files after it that
# read that run come late enough for it to be ready, so no worker waits. Per file on 2 CPU cores (seconds, the sum of
# its tests' times in a 35-minute `make test` with --junitxml; randomization, benchmark_scripts, reach_learning,
# benchmarks, vision, checkpoint, tbptt and settings less what their quick compiles saved since, at 2.7 times the CPU
# seconds measured in benchmarks/results/suite_profile): randomization 478, evaluation 286, ihom 237, vision 234,
# analysis 234, distributed 223, benchmarks 219, ppo_learning 203, notebook 203, locomotion 201, cli 165,
# benchmark_scripts 132, docs 140, warp 121, checkpoint 104, run_safety 100, nets 81, reach_sequential 67, host_env 65,
# tbptt 62, training_video 61, settings 59, envs 57, config 47, parallel 47; every file not listed is shorter and
# follows in name order.
LONGEST_FIRST = (
    "test_evaluation", "test_randomization", "test_ihom", "test_vision", "test_analysis", "test_distributed",
    "test_benchmarks", "test_ppo_learning", "test_notebook", "test_locomotion", "test_cli", "test_docs",
    "test_benchmark_scripts", "test_warp", "test_checkpoint", "test_run_safety", "test_nets", "test_reach_sequential",
    "test_host_env", "test_tbptt", "test_training_video", "test_settings", "test_envs", "test_config", "test_parallel",
)


# Fixtures that train an agent for minutes: a test that asks for one is in the slow tier (`make test-fast` leaves it
# out) without saying so itself. Other slow tests carry `@pytest.mark.slow` (tests/README.md lists the tiers).
TRAINING_FIXTURES = {"cortical_reach"}


@pytest.hookimpl(tryfirst=True)  # before pytest's own hook deselects by marker (`-m "not slow"`)
def pytest_collection_modifyitems(items):
    """Mark the tests that use a training fixture as slow, and order the collected tests by their file's place in
    `LONGEST_FIRST` (stable within a file)."""
    for item in items:
        if TRAINING_FIXTURES & set(item.fixturenames):
            item.add_marker(pytest.mark.slow)
    rank = {name: place for place, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: (rank.get(item.path.stem, len(rank)), str(item.path)))


@pytest.fixture(scope="session")
def gl_problem() -> str | None:
    """Why MuJoCo can make no OpenGL context here (with what to install), asked of MuJoCo itself; None when it can."""
    import mujoco

    try:
        mujoco.Renderer(mujoco.MjModel.from_xml_string("<mujoco/>"), 8, 8).close()
    except Exception as error:  # MuJoCo raises several kinds of error when no OpenGL context can be made
        return (f"no OpenGL backend for MuJoCo with MUJOCO_GL={os.environ.get('MUJOCO_GL')} ({error}); install "
                "libegl-mesa0 and set MUJOCO_GL=egl")
    return None


@pytest.fixture(scope="session")
def opengl(gl_problem):
    """For tests that render with OpenGL (MuJoCo's renderer): skipped, with the reason and what to install, where
    MuJoCo can make no OpenGL context (a machine without Mesa's EGL; `.ci/run` installs it, so CI runs them). Only
    the probe is guarded: an error of our own rendering code fails the test."""
    if gl_problem:
        pytest.skip(gl_problem)


@pytest.fixture
def quick_compiles():
    """For a test that runs every program it compiles only briefly (a cycle or two, a few steps): JAX compiles them
    with XLA's CPU backend at optimisation level 0 and LLVM's expensive passes off (tests/quick_compile.py says what
    that saves), and back to the default afterwards, leaving no quick program in JAX's in-process caches."""
    from quick_compile import quick_compilation

    with quick_compilation():
        yield


@pytest.fixture(scope="module")
def quick_file_compiles():
    """`quick_compiles` for a whole test file whose programs all run briefly (`pytestmark =
    pytest.mark.usefixtures("quick_file_compiles")`): set up before the file's other module fixtures, so they compile
    quickly too, and the in-process caches cleared once, after its last test. Such a file asks for no training
    fixture (`TRAINING_FIXTURES`), which would otherwise train at optimisation level 0 if first asked for there."""
    from quick_compile import quick_compilation

    with quick_compilation():
        yield


# The reach run of the brain-area model (`cortical`) that test_reach_learning checks and that the probing tests and
# notebook analyse: trained once per session. 32 environments x 32 steps per cycle, 16 minibatch updates of 256
# transitions, gamma 0.95, no entropy bonus, 30-step episodes (0.6 s), areas a quarter of AngoraPy's or less and a
# GRU premotor layer. Measured on 2 CPU cores: 75 s, final goal distance 0.044 m (test_reach_learning's bar 0.056).
# Of a cycle's run time, 91% is MJX's physics of the 32 hands, so smaller areas would not shorten the run
# (benchmarks/results/env_train_throughput/profile_cycle_reach_cortical_tests_cpu.json).
CORTICAL_AREAS = "{SSC_1: 64, SSC_2: 32, SPL: 32, IPL: 32, IPS: 32, MCC: 32, LPFC: 32, PMC_in: 64, PMC: 64, M1: 64}"
CORTICAL_REACH = [
    "env.options.max_episode_steps=30",
    "ppo.seed=0", "ppo.num_cycles=120", "ppo.num_envs=32", "ppo.rollout_length=32", "ppo.chunk_length=16",
    "ppo.minibatch_size=256", "ppo.num_epochs=4", "ppo.learning_rate=1e-3", "ppo.gamma=0.95",
    "ppo.network.name=cortical", "ppo.network.cell=gru", "ppo.network.width=64", f"ppo.network.areas={CORTICAL_AREAS}",
    "checkpoint.every=120", "checkpoint.snapshot_every=0", "checkpoint.best_metric=null",
    "logging.progress=none", "logging.report=false",
]


@pytest.fixture(scope="session")
def cortical_reach(tmp_path_factory, worker_id):
    """The trained reach run of the brain-area model: `run_dir` (its final checkpoint) and `history` (its metrics per
    cycle). Trained once per session, also when pytest-xdist's workers (`make test`) run the files that use it: the
    first to ask trains it in a folder they share, the others wait for it and read it."""
    import angora_jax as aj

    def train(root):
        run = aj.train("shadow_reach", [*CORTICAL_REACH, f"logging.run_root={root}", "logging.run_name=cortical"])
        return SimpleNamespace(run_dir=run.run_dir, history=run.history)

    if worker_id == "master":
        return train(tmp_path_factory.mktemp("reach"))
    root = tmp_path_factory.getbasetemp().parent / "cortical_reach"
    finished, failed = root / "finished", root / "failed"
    try:
        root.mkdir()
    except FileExistsError:
        deadline = time.monotonic() + 1800
        while not (finished.exists() or failed.exists()) and time.monotonic() < deadline:
            time.sleep(1)
        if not finished.exists():
            pytest.fail(f"The worker training the shared cortical reach run failed or timed out (see {root}).")
        history = [json.loads(line) for line in (root / "cortical" / "metrics.jsonl").read_text().splitlines()]
        return SimpleNamespace(run_dir=root / "cortical", history=history)
    try:
        run = train(root)
    except BaseException:
        failed.touch()
        raise
    finished.touch()
    return run
