"""Result files (recordings, evaluations, analyses, plots) that are either whole or absent.

A file is written under a temporary name beside its own and renamed when it is complete, so a Ctrl-C, a full disk or
a crash while it is written leaves no half file behind: nothing that a later command would refuse to overwrite, or
read as a result.
"""

from __future__ import annotations

import contextlib
import errno
import os
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def written_whole(path: str | Path, replace: bool = True) -> Iterator[Path]:
    """Yield the temporary path to write `path`'s contents to (beside it, same extension, so writers that read the
    format from the name still can); when the block ends without an error it becomes `path`, else it is removed.
    With `replace=False` an existing `path` is never overwritten: FileExistsError, before anything is written when it
    exists already, and the new file dropped when another writer made it meanwhile."""
    path = Path(path)
    draft = path.with_name(f".{path.stem}.{os.getpid()}.partial{path.suffix}")
    if not replace and path.exists():  # named before writing, so a full disk is not blamed on the kept file
        raise _kept(path)
    try:
        yield draft
        if replace:
            os.replace(draft, path)
        else:
            _publish_new(draft, path)
    except OSError as error:
        # The system's message names the file asked for, not the draft: writers name the draft as a str or a Path
        # (imageio), or not at all (a full disk met when Pillow flushes). Errors of our own (errno None) keep theirs.
        if error.errno is not None and (error.filename is None or Path(os.fsdecode(error.filename)).name == draft.name):
            error.filename = str(path)
        raise
    finally:
        draft.unlink(missing_ok=True)


def _kept(path: Path) -> FileExistsError:
    """The refusal to write over the existing `path`."""
    return FileExistsError(f"{path} exists and is never overwritten.")


def _publish_new(draft: Path, path: Path) -> None:
    """`draft` as `path`, which must not exist: a hard link, which the system refuses when `path` exists, so a second
    writer that made it after the check above is not overwritten either. Where the file system has no hard links, a
    check and a rename."""
    try:
        os.link(draft, path)
    except FileExistsError:
        raise _kept(path) from None
    except OSError as error:
        if error.errno not in (errno.EPERM, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EMLINK):
            raise
        if path.exists():
            raise _kept(path) from None
        os.replace(draft, path)


def unwritable_folder(out: str | Path) -> str | None:
    """Why no file can be written at `out`, or None: the nearest existing folder on its way (its own, or the one its
    missing folders would be made in) is a file, or is not writable. Asked before work that takes minutes (rendering
    a video, training an encoder), which otherwise ended only then, in "[Errno 17] File exists: 'notes.txt'"."""
    folder = next(parent for parent in Path(out).absolute().parents if parent.exists())
    if not folder.is_dir():
        return f"{folder} is a file, not a folder"
    return None if os.access(folder, os.W_OK) else f"{folder} is not writable"
