"""A checkpoint's manifest: every file of the checkpoint's folder with its size and SHA-256, written last.

A checkpoint whose folder has a manifest was saved whole; `verify` then tells an intact checkpoint from one that
a full disk, a copy cut short or a stray edit damaged, and names the file, before Orbax reads anything.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

MANIFEST_FILE = "manifest.json"


def file_digest(path: Path) -> str:
    """SHA-256 of the file's bytes, in hex."""
    digest = hashlib.sha256()
    with path.open("rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def write_manifest(folder: Path) -> None:
    """List every file under `folder` (relative path -> size in bytes and SHA-256) in `folder/manifest.json`, written
    to a temporary name and renamed, so that a manifest is either whole or absent."""
    files = {
        path.relative_to(folder).as_posix(): {"bytes": path.stat().st_size, "sha256": file_digest(path)}
        for path in sorted(folder.rglob("*"))
        if path.is_file() and path.name != MANIFEST_FILE
    }
    draft = folder / f"{MANIFEST_FILE}.tmp"
    with draft.open("w") as file:
        json.dump({"files": files}, file, indent=1)
        file.flush()
        os.fsync(file.fileno())
    draft.replace(folder / MANIFEST_FILE)


def verify(folder: Path) -> str | None:
    """What is wrong with the checkpoint in `folder` by its manifest (the first damaged file and how), None when every
    listed file is there with its size and checksum; "no manifest" when it has none (saved by an angora_jax before
    manifests, or stopped between Orbax's save and the manifest: then it cannot be checked), unless it lacks even the
    `meta` item that every checkpoint is saved with (a folder emptied or made by hand)."""
    path = folder / MANIFEST_FILE
    if not path.is_file():
        if not any((folder / "meta").glob("*")):
            return f"{folder / 'meta'} is missing or empty (a folder emptied or cut short) and it has no manifest"
        return "no manifest"
    try:
        files = json.loads(path.read_text())["files"]
        listed = {name: (int(entry["bytes"]), str(entry["sha256"])) for name, entry in files.items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return f"its manifest {path} is unreadable"
    for name, (size, checksum) in listed.items():
        file = folder / name
        if not file.is_file():
            return f"{file} is missing"
        if file.stat().st_size != size:
            return f"{file} has {file.stat().st_size} bytes, {size} were saved"
        if file_digest(file) != checksum:
            return f"{file} differs from what was saved (checksum)"
    return None
