"""`angora-jax doctor`: what this machine gives angora_jax, and what to install when something is missing.

It reports the package versions that matter (JAX and its CUDA plugin, MuJoCo, MJX, Warp, ...), the devices JAX sees
with their memory, the NVIDIA driver, which physics implementation the MuJoCo tasks will use and why, and whether
MuJoCo can render off screen. `versions()` and `devices()` are also written into each run directory when a run starts.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import os
import platform
import shutil
import subprocess
import sys
import warnings
from dataclasses import dataclass, field

import jax

from angora_jax.envs.mjx_env import WARP_REQUIREMENT, choose_impl, on_gpu
from angora_jax.opengl_backend import GL_HINT
from angora_jax.ppo.memory import GIB, device_memory
from angora_jax.wording import agreeing, counted

# myo-sim (optional) holds the MyoHand's muscles and tendons: a run of a MyoHand task depends on its version.
PACKAGES = ("jax", "jaxlib", "jax-cuda13-plugin", "jax-cuda12-plugin", "mujoco", "mujoco-mjx", "warp-lang", "flax",
            "optax", "distrax", "orbax-checkpoint", "gymnasium", "gymnasium-robotics", "myo-sim", "angora-jax")
# Required packages and the module each provides (a package may be present as files without its metadata, as
# gymnasium-robotics is when only its Shadow-hand assets are copied: the module is what must be found).
REQUIRED = {"jax": "jax", "jaxlib": "jaxlib", "mujoco": "mujoco", "mujoco-mjx": "mujoco.mjx", "flax": "flax",
            "optax": "optax", "distrax": "distrax", "orbax-checkpoint": "orbax.checkpoint", "gymnasium": "gymnasium",
            "gymnasium-robotics": "gymnasium_robotics"}
# angora-jax is not on PyPI: its extras install from the clone (docs/installation.md).
CUDA_INSTALL = ('make gpu in the clone, or pip install -c constraints.txt -e ".[cuda]" there (a CUDA 13 build of JAX '
                'and warp-lang; NVIDIA driver >= 580)')


@dataclass
class Diagnosis:
    """The findings: `rows` (section, name, value) to print, `problems` (what is broken, with the fix: exit code 1)
    and `advice` (what would make this machine faster or complete; not errors)."""

    rows: list[tuple[str, str, str]] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    advice: list[str] = field(default_factory=list)

    def format(self) -> str:
        width = max(len(name) for _, name, _ in self.rows)
        lines, section = [], None
        for where, name, value in self.rows:
            if where != section:
                lines.append(f"{where}:")
                section = where
            lines.append(f"  {name:<{width}}  {value}")
        lines += [f"PROBLEM: {text}" for text in self.problems] + [f"advice: {text}" for text in self.advice]
        lines.append("OK: angora_jax can train here." if not self.problems else
                     f"{counted(len(self.problems), 'problem')}: fix {agreeing(len(self.problems), 'it', 'them')} as "
                     "shown above.")
        return "\n".join(lines)


def versions() -> dict[str, str | None]:
    """Installed versions of the packages angora_jax runs on (None: not installed)."""
    found = {}
    for name in PACKAGES:
        try:
            found[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            found[name] = None
    return found


def devices() -> list[dict[str, str | float | None]]:
    """The local devices JAX sees: name, kind and memory in GiB (None when unknown)."""
    return [{"device": str(d), "kind": d.device_kind,
             "memory_gib": None if device_memory(d) is None else round(device_memory(d) / GIB, 1)}
            for d in jax.local_devices()]


def diagnose() -> Diagnosis:
    """Inspect this machine (never raises for a missing piece: it becomes a problem or advice with its fix)."""
    report = Diagnosis()
    report.rows.append(("system", "python", f"{platform.python_version()} ({sys.executable})"))
    report.rows.append(("system", "platform", platform.platform()))
    installed = versions()
    for name, version in installed.items():
        found = version is not None or (name in REQUIRED and _importable(REQUIRED[name]))
        if version is not None or name in REQUIRED:
            report.rows.append(("packages", name, version or ("files only" if found else "MISSING")))
        if name in REQUIRED and not found:
            report.problems.append(f"{name} is not installed: install angora_jax with its requirements, `make` in "
                                   "the clone or pip install -c constraints.txt -e . there.")
    _devices(report)
    _physics(report, installed)
    _rendering(report)
    return report


def _devices(report: Diagnosis) -> None:
    for entry in devices():
        memory = "memory unknown" if entry["memory_gib"] is None else f"{entry['memory_gib']} GiB"
        report.rows.append(("devices", entry["device"], f"{entry['kind']}, {memory}"))
    driver = _nvidia_driver()
    report.rows.append(("devices", "NVIDIA driver", driver or "none (no nvidia-smi)"))
    if driver and not on_gpu():
        report.problems.append(f"An NVIDIA GPU is present but JAX sees only {jax.default_backend()}: {CUDA_INSTALL}.")
    if on_gpu() and driver and int(driver.split(".")[0]) < 580:
        report.advice.append(f"NVIDIA driver {driver} is older than 580, which CUDA 13 builds of JAX and Warp need.")


def _physics(report: Diagnosis, installed: dict[str, str | None]) -> None:
    impl, why = choose_impl("auto")
    report.rows.append(("physics", "MuJoCo tasks", f"MJX {impl} implementation ({why})"))
    report.rows.append(("physics", "classic tasks", "pure JAX"))
    wanted = WARP_REQUIREMENT.split("==")[1]
    if on_gpu() and installed["warp-lang"] is None:
        report.advice.append(f"pip install {WARP_REQUIREMENT} for MuJoCo Warp physics (4.6x faster cube training).")
    if installed["warp-lang"] not in (None, wanted):
        report.advice.append(f"warp-lang {installed['warp-lang']} is installed; mujoco-mjx {installed['mujoco-mjx']} "
                             f"is tested with {wanted}: pip install {WARP_REQUIREMENT}.")


def _rendering(report: Diagnosis) -> None:
    import mujoco

    backend = f"MUJOCO_GL={os.environ.get('MUJOCO_GL', 'unset (GLFW, needs a display)')}"
    model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom size='0.1'/></worldbody></mujoco>")
    try:
        with warnings.catch_warnings():  # GLFW warns before it fails without a display; the row says it
            warnings.simplefilter("ignore")
            renderer = mujoco.Renderer(model, 16, 16)
    except Exception as error:  # each GL backend raises its own type
        report.rows.append(("rendering", "off screen", f"no: {backend} ({str(error).split(',')[0]})"))
        report.advice.append(f"Videos (angora-jax render) cannot be made. {GL_HINT}")
        return
    renderer.close()
    report.rows.append(("rendering", "off screen", f"yes, {backend}"))


def _importable(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:  # a parent package is missing
        return False


def _nvidia_driver() -> str | None:
    if shutil.which("nvidia-smi") is None:
        return None
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=driver_version", "--format=csv,noheader"], capture_output=True,
                             text=True, timeout=20, check=True).stdout.split()
    except (subprocess.SubprocessError, OSError):
        return None
    return out[0] if out else None
