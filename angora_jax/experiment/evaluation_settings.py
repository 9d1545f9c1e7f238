"""The settings of `evaluate` (angora_jax.experiment.evaluation) that the `angora-jax evaluate` command offers as
options, apart from that module (JAX, the agent, C MuJoCo), so that the command's parser, which every command and
`--help` builds, imports none of it."""

# Episodes run at once by default: enough to spread the fixed cost of each step's JAX calls, few enough that a small
# evaluation still fills the batch.
DEFAULT_BATCH = 32
# Where the episodes run: "cpu", the eager path on the host; "batched", all at once on the training path.
PATHS = ("cpu", "batched")
