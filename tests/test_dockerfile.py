"""The Dockerfile is not built in CI (docs/docker.md says why), so this keeps it honest: it starts from a Python the
package supports, holds every pip install to constraints.txt, names only pins and extras that exist, copies what
exists, and ends with `angora-jax doctor` as its check."""

import re
import tomllib
from pathlib import Path

from packaging.specifiers import SpecifierSet
from packaging.utils import canonicalize_name

from angora_jax.cli import parser

ROOT = Path(__file__).resolve().parents[1]


def instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) of the Dockerfile, continuation lines joined, comments dropped."""
    lines = [line for line in (ROOT / "Dockerfile").read_text().splitlines() if not line.lstrip().startswith("#")]
    text = re.sub(r"\\\n\s*", " ", "\n".join(lines))
    return [tuple(line.split(maxsplit=1)) for line in text.splitlines() if line.strip()]


def test_the_dockerfile_installs_the_pinned_package_and_checks_it_with_doctor():
    steps = instructions()
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    pins = {canonicalize_name(name): version for name, version in
            (line.split("==") for line in (ROOT / "constraints.txt").read_text().split() if "==" in line)}
    (base,) = [args for kind, args in steps if kind == "FROM"]
    python = re.fullmatch(r"python:(\d+\.\d+)-slim-\w+", base)
    assert python and python[1] in SpecifierSet(project["requires-python"]), base
    installs = [args for kind, args in steps if kind == "RUN" and "pip install" in args]
    assert installs, "the package is installed"
    for command in installs:
        assert "-c constraints.txt" in command, f"not held to the pins: {command}"
        for extras in re.findall(r"\.\[([\w,-]+)\]", command):
            assert set(extras.split(",")) <= set(project["optional-dependencies"]), command
        for name, version in re.findall(r"([\w.-]+)==([\w.]+)", command):
            assert pins[canonicalize_name(name)] == version, f"{name}=={version} is not constraints.txt's pin"
    assert any(".[cuda]" in command for command in installs), "CUDA JAX and warp-lang: the cuda extra"
    for kind, args in steps:
        if kind == "COPY":
            for source in args.split()[:-1]:
                assert (ROOT / source).exists(), f"COPY {source}: no such file"
    assert steps[-1] == ("RUN", "angora-jax doctor"), "doctor is the build's last step"
    assert parser().parse_args(["doctor"]).handler.__name__ == "command_doctor"
