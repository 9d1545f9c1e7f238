"""The operating system's errors (a full disk, a read-only mount, permissions) as one sentence with the fix."""

from __future__ import annotations

import errno

# What to do about the errors the operating system reports, by errno.
OS_ERROR_FIXES = {
    errno.ENOSPC: "free space on that disk (or move the run root to a larger one)",
    errno.EDQUOT: "free space within your disk quota (or move the run root)",
    errno.EROFS: "the file system is read-only: choose a writable place (logging.run_root, --out)",
    errno.EACCES: "you may not write or read there: choose another place or fix its permissions",
    errno.EPERM: "you may not write or read there: choose another place or fix its permissions",
    errno.ENAMETOOLONG: "shorten the path or name",
    errno.EIO: "the disk or network file system failed: check the mount, then retry",
    errno.ENOTDIR: "a part of the path is a file, not a folder: fix the path",
    errno.EISDIR: "the path is a folder: give a file",
    errno.EEXIST: "a file is in the way where a folder must be made: choose another path (logging.run_root, --out)",
    errno.ENOENT: "a folder on the way does not exist or cannot be made there: check the path",
}


def os_error_message(error: OSError) -> str:
    """An OSError as one sentence: what failed, on which file, and the fix; a run interrupted this way keeps what it
    saved before (`angora-jax check RUN_DIR`, then `resume`)."""
    where = f" ({error.filename})" if error.filename else ""
    fix = OS_ERROR_FIXES.get(error.errno, "fix the cause and retry")
    during_a_run = error.errno in (errno.ENOSPC, errno.EDQUOT, errno.EIO)
    return f"{error.strerror or error}{where}: {fix}." + (
        " A run stopped by it keeps every checkpoint saved before: `angora-jax check RUN_DIR` shows them, "
        "`angora-jax resume RUN_DIR` continues." if during_a_run else "")
