"""MuJoCo's OpenGL backend, which `MUJOCO_GL` chooses and MuJoCo loads when it is imported.

A backend whose library is missing (MUJOCO_GL=osmesa without libosmesa6) or a name MuJoCo does not know fails
`import mujoco` itself, with an error from inside PyOpenGL ("'NoneType' object has no attribute 'glGetError'"), so
every command and `import angora_jax` would fail, rendering or not. Importing this module imports MuJoCo and names the
cause and the fix instead; the package imports it first, before anything else imports MuJoCo, so it imports nothing
of the package.
"""

from __future__ import annotations

import itertools
import os
import sys
from pathlib import Path

GL_HINT = (
    "Rendering needs an OpenGL backend: on a machine without a display install `libegl1 libegl-mesa0` and set "
    "MUJOCO_GL=egl, or install `libosmesa6` and set MUJOCO_GL=osmesa, before starting Python."
)


class OpenGLBackendError(ImportError):
    """MuJoCo cannot be imported with the OpenGL backend `MUJOCO_GL` names."""


# The backend MuJoCo loaded when it was imported: setting MUJOCO_GL later (a notebook cell after the import) changes
# nothing until Python restarts.
LOADED = os.environ.get("MUJOCO_GL")


def changed_since_import() -> str | None:
    """Why rendering cannot use the `MUJOCO_GL` set now, when it was set or changed after MuJoCo was imported (it
    loaded another backend then); None when it is the one loaded."""
    now = os.environ.get("MUJOCO_GL")
    if now == LOADED:
        return None
    return (f"MUJOCO_GL={now} was set after MuJoCo was imported, which loaded "
            f"{'MUJOCO_GL=' + LOADED if LOADED else 'its default (GLFW, which needs a display)'} then and keeps it: "
            f"set MUJOCO_GL={now} before importing angora_jax (in a notebook: restart the kernel and set it in the "
            "first cell, or in the environment that starts Jupyter)")


def import_mujoco() -> None:
    """Import MuJoCo; when the backend `MUJOCO_GL` names cannot load, exit 2 with the cause and the fix under the
    `angora-jax` command, or raise OpenGLBackendError in Python (a notebook's `import angora_jax`)."""
    try:
        import mujoco  # noqa: F401
    except ModuleNotFoundError as error:
        if error.name == "mujoco" or "MUJOCO_GL" not in os.environ:
            raise
        _refuse(error)
    except Exception as error:  # PyOpenGL's AttributeError, MuJoCo's RuntimeError for an unknown name, ...
        if "MUJOCO_GL" not in os.environ:
            raise
        _refuse(error)


def _refuse(error: Exception) -> None:
    backend = os.environ["MUJOCO_GL"]
    message = (
        f"MuJoCo cannot be imported with MUJOCO_GL={backend} ({type(error).__name__}: {error}): MuJoCo loads that "
        f"OpenGL backend when it is imported, and its library is missing or the name is not one MuJoCo knows (egl, "
        f"osmesa, glfw). Install it, choose another, or unset MUJOCO_GL where nothing is rendered (training, "
        f"evaluation). {GL_HINT}"
    )
    if _running_the_command():
        print(f"angora-jax: {message}", file=sys.stderr)
        raise SystemExit(2)
    raise OpenGLBackendError(message) from None


def _running_the_command() -> bool:
    """Whether this process is the `angora-jax` command (or `python -m angora_jax.cli`), whose errors end in exit 2."""
    original = getattr(sys, "orig_argv", [])
    as_module = any(a == "-m" and b.startswith("angora_jax.cli") for a, b in itertools.pairwise(original))
    return Path(sys.argv[0]).name == "angora-jax" or as_module


import_mujoco()
