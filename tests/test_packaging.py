"""The package as a lab installs it: a wheel that carries the shipped configs, one copy of them in the repository."""

import subprocess
import sys
import zipfile
from pathlib import Path

from angora_jax.experiment.config import CONFIGS, list_configs

ROOT = Path(__file__).resolve().parents[1]


def test_the_repository_configs_folder_is_the_package_data_not_a_copy():
    assert (ROOT / "configs").resolve() == CONFIGS.resolve() == (ROOT / "angora_jax" / "configs").resolve()


def test_the_wheel_ships_every_config(tmp_path):
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(tmp_path), str(ROOT)],
                   check=True, capture_output=True, timeout=300)
    (wheel,) = tmp_path.glob("angora_jax-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {f"angora_jax/configs/{name}.yaml" for name in list_configs()} <= names
    assert "angora_jax/cli/__init__.py" in names and "angora_jax/envs/shadow_hand/ihom.py" in names
    assert "angora_jax/envs/myohand/reachable_postures.npz" in names, "MyoHandPose(targets=\"reachable\") draws from it"
    assert "angora_jax/ppo/__init__.pyi" in names, "lazy_loader reads each package's public names from its stub"
    assert not any(name.startswith("configs/") for name in names)
