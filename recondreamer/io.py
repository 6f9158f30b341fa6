"""Atomic writes: a killed process never leaves a file or directory that looks complete.

Files are written to a temporary sibling and renamed into place (``os.replace`` is atomic on
POSIX within one file system). Directories are built under a temporary sibling name and renamed
when complete; an existing destination is replaced only after the new one is fully written, and
only when it is an earlier output of the same kind (each output directory carries a small
``.recondreamer-output`` marker naming its kind): an ``--out`` that names an unrelated folder, a
plain file, an input or a folder holding inputs is refused before anything is written.
A write that fails because its file system is full raises ``OutputWriteError`` naming the
output (the previous file or directory is left as it was and the temporary is removed).
"""

from __future__ import annotations

import contextlib
import errno
import glob
import json
import os
import shutil
import socket
import tempfile
from collections.abc import Iterator
from pathlib import Path

from recondreamer.errors import RecondreamerError

OUTPUT_MARKER = ".recondreamer-output"  # inside every directory atomic_directory writes: its kind


class OutputPathError(RecondreamerError):
    """An output path names something that is not an earlier output of the same kind."""


class OutputWriteError(RecondreamerError):
    """An output could not be written because its file system is full; nothing was replaced."""


_DISK_FULL_ERRNOS = (errno.ENOSPC, errno.EDQUOT)
# Free bytes under which a failed write is put down to a full file system: writers that do not
# pass the OS error on (torch.save of a path raises "unexpected pos", numpy's tofile a bare
# "N requested and M written") leave only the full disk as the evidence.
_NEARLY_FULL_BYTES = 1 << 20


def _free_bytes(directory: Path) -> int | None:
    try:
        return shutil.disk_usage(directory).free
    except OSError:
        return None


def _disk_full_error(path: Path, error: BaseException, replacing: bool) -> OutputWriteError | None:
    """``OutputWriteError`` naming ``path`` when ``error`` (raised while writing it) comes from
    a full file system (ENOSPC/EDQUOT anywhere in its chain, or almost no space left); else None.
    Called before the temporary is removed, while the file system is still as full as it was."""
    chain, seen = [], set()
    while error is not None and id(error) not in seen:
        seen.add(id(error))
        chain.append(error)
        error = error.__cause__ or error.__context__
    free = _free_bytes(path.parent)
    full = any(isinstance(e, OSError) and e.errno in _DISK_FULL_ERRNOS for e in chain)
    if not full and not (isinstance(chain[0], (OSError, RuntimeError)) and free is not None and free < _NEARLY_FULL_BYTES):
        return None
    kept = "the earlier one is unchanged" if replacing else "nothing was written"
    space = f", {free} bytes free" if free is not None and free < _NEARLY_FULL_BYTES else ""
    return OutputWriteError(f"{path}: could not be written: no space left on its file system{space} ({kept})")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _default_mode(is_dir: bool) -> int:
    """The mode ``open``/``mkdir`` would give: tempfile's private 0600/0700 would leak into results."""
    return (0o777 if is_dir else 0o666) & ~_umask()


def _temporary_prefix(path: Path) -> str:
    """Prefix of the temporary siblings this process makes for ``path``: the host and process id
    in the name let a later writer tell a dead process's leftovers from another writer's work."""
    return f".{path.name}.{socket.gethostname()}.{os.getpid()}."


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def remove_stale_temporaries(path: Path) -> list[Path]:
    """Delete the temporary siblings of ``path`` left by killed processes of this host (a kill -9
    during a write leaves one behind); those of live processes and other hosts are kept.
    Returns what was deleted."""
    host = socket.gethostname()
    removed = []
    for leftover in path.parent.glob(f"{glob.escape(f'.{path.name}.{host}.')}*.tmp"):
        pid = leftover.name[len(f".{path.name}.{host}.") :].split(".", 1)[0]
        if not pid.isdigit() or _process_alive(int(pid)):
            continue
        if leftover.is_dir():
            shutil.rmtree(leftover, ignore_errors=True)
        else:
            leftover.unlink(missing_ok=True)
        removed.append(leftover)
    return removed


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary file path next to ``path``; rename it onto ``path`` if the block succeeds."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(path)
    fd, tmp_name = tempfile.mkstemp(prefix=_temporary_prefix(path), suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    tmp.chmod(_default_mode(is_dir=False))
    try:
        yield tmp
        os.replace(tmp, path)
    except (OSError, RuntimeError) as error:
        failure = _disk_full_error(path, error, path.exists())
        if failure is None:
            raise
        raise failure from error
    finally:
        if tmp.exists():
            tmp.unlink()


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    write_bytes_atomic(path, text.encode("utf-8"))


def write_json_atomic(path: str | os.PathLike, obj, indent: int = 2) -> None:
    write_text_atomic(path, json.dumps(obj, indent=indent, sort_keys=False) + "\n")


def output_kind(path: str | os.PathLike) -> str | None:
    """The kind of output a directory written by ``atomic_directory`` holds (None: not one)."""
    marker = Path(path) / OUTPUT_MARKER
    try:
        return marker.read_text().strip() if marker.is_file() else None
    except OSError:
        return None


def check_replaceable(path: str | os.PathLike, kind: str) -> None:
    """Raise unless ``path`` is absent, an empty directory, or an earlier ``kind`` output."""
    path = Path(path)
    if not (path.exists() or path.is_symlink()):
        return
    if path.is_symlink() or not path.is_dir():
        raise OutputPathError(f"{path}: exists and is not a directory; refusing to replace it with a {kind} (choose another output path)")
    if path.resolve() == Path.cwd().resolve() or path.resolve() in Path.cwd().resolve().parents:
        raise OutputPathError(f"{path}: is the working directory or one of its parents; refusing to replace it with a {kind}")
    found = output_kind(path)
    if found == kind or not any(path.iterdir()):
        return
    what = f"a {found} output" if found else f"not marked as a recondreamer output (no {OUTPUT_MARKER})"
    raise OutputPathError(f"{path}: exists and is {what}; refusing to replace it with a {kind} (remove it or choose another output path)")


@contextlib.contextmanager
def atomic_directory(path: str | os.PathLike, kind: str) -> Iterator[Path]:
    """Yield an empty temporary directory; on success it replaces ``path`` in one rename.

    ``kind`` names what the directory holds (``scene``, ``renders``, ...). An existing ``path``
    is replaced only when it is an earlier output of the same kind or empty (``check_replaceable``,
    before anything is written). On failure the temporary directory is removed and an existing
    ``path`` is left untouched.
    """
    path = Path(path)
    check_replaceable(path, kind)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(path)
    tmp = Path(tempfile.mkdtemp(prefix=_temporary_prefix(path), suffix=".tmp", dir=path.parent))
    tmp.chmod(_default_mode(is_dir=True))
    try:
        yield tmp
        (tmp / OUTPUT_MARKER).write_text(kind + "\n")
        if path.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent))
            try:
                os.replace(path, old / path.name)
                try:
                    os.replace(tmp, path)
                except BaseException:
                    os.replace(old / path.name, path)  # the earlier output back in place
                    raise
            finally:
                shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    except (OSError, RuntimeError) as error:
        failure = _disk_full_error(path, error, path.exists())
        if failure is None:
            raise
        raise failure from error
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)


SNAKEMAKE_FOLDER_STAMP = ".snakemake_timestamp"  # Snakemake dates a directory() output by this file inside it


def restamp_edited_folder(folder: str | os.PathLike) -> list[Path]:
    """Carry edits made inside a workflow's output folder onto the folder's date.

    Snakemake dates a ``directory()`` output by the ``.snakemake_timestamp`` file it leaves inside
    when the job ends, so a file edited in place later (a scene touched up by hand) leaves the
    folder's date, and everything computed from it, looking up to date. When a file inside is
    newer than that stamp, the stamp takes the newest file's modification time and the edited
    files are returned (nothing else is written); a folder without a stamp (not a finished
    Snakemake output, or replaced as a whole) is left alone and gives ``[]``.
    """
    folder = Path(folder)
    stamp = folder / SNAKEMAKE_FOLDER_STAMP
    try:
        stamped = stamp.stat().st_mtime_ns
    except FileNotFoundError:
        return []
    edited: list[tuple[int, Path]] = []
    for directory, _, names in os.walk(folder):
        for name in names:
            path = Path(directory, name)
            if path == stamp:
                continue
            modified = path.stat(follow_symlinks=False).st_mtime_ns
            if modified > stamped:
                edited.append((modified, path))
    if edited:
        newest = max(modified for modified, _ in edited)
        os.utime(stamp, ns=(newest, newest))
    return sorted(path for _, path in edited)
