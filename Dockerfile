# angora_jax for an NVIDIA GPU cluster: a CUDA 13 build of JAX, MuJoCo Warp (warp-lang) and the package, at the
# versions of constraints.txt, checked by `angora-jax doctor` as the build's last step. docs/docker.md tells how to
# build it, run it with `--gpus all` and turn it into an Apptainer image for SLURM.
#
# Not built in CI: CI (.ci/run) runs `make test` on a CPU machine, and where this was written (a CI-like container)
# the docker client is installed but no Docker daemon runs, so nothing can be built; the image's CUDA wheels would
# also be gigabytes to download on every run.
# tests/test_dockerfile.py keeps this file honest instead: the Python it starts from is one the package supports,
# every pip install is held to constraints.txt, the extras it names exist, what it copies exists, doctor is its check.
#
#   docker build -t angora-jax .
#   docker run --rm --gpus all angora-jax angora-jax doctor

# The Python that constraints.txt was resolved on.
FROM python:3.11-slim-bookworm

# EGL for MuJoCo's off-screen rendering (angora-jax render): Mesa's on a CPU; on a GPU host the NVIDIA container
# toolkit mounts the driver's own EGL when the "graphics" capability is asked for.
RUN apt-get update \
    && apt-get install -y --no-install-recommends libegl1 libegl-mesa0 libgl1 \
    && rm -rf /var/lib/apt/lists/*
ENV MUJOCO_GL=egl \
    NVIDIA_DRIVER_CAPABILITIES=compute,utility,graphics \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

WORKDIR /opt/angora_jax
# The package (the shipped configs are inside it) and what pip needs to build it; the CUDA libraries come as pip
# wheels with jax[cuda13], so the base image needs no CUDA toolkit, only the host's driver (>= 580) at run time.
COPY pyproject.toml constraints.txt README.md ./
COPY angora_jax ./angora_jax
RUN pip install -c constraints.txt ".[cuda]"

WORKDIR /work
# A build machine has no GPU: here doctor checks that every package imports and what physics and rendering the image
# offers (exit code 1 when something required is missing). On the cluster, `angora-jax doctor` in the container also
# checks that JAX sees the GPUs. Not a HEALTHCHECK: each probe would start JAX on the GPUs beside the training job.
RUN angora-jax doctor
