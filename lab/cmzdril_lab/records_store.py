"""The committed run records, compact: each study folder of ``results/`` is one ``NAME.tar.xz``.

A clone holds ``results/runs.tar.xz``, ``results/tuning/NAME.tar.xz``, ... instead of thousands of
small files. Whatever reads a folder of records calls :func:`materialize` first: where the folder lies in an
archived study (or is one), the archive is unpacked beside it, once, and again only when the archive
changed. The unpacked folders are ignored by git (``results/.gitignore``); :func:`pack` writes an
archive back from its folder, byte for byte the same for the same files, so a study that gained runs
is committed as one changed file.

Nothing is lost: a folder is replaced from its archive only while it holds exactly what was unpacked
into it; new or changed runs in it are refused in one line until they are packed.
"""
from __future__ import annotations

import fnmatch
import io
import json
import os
import shutil
import tarfile
from pathlib import Path, PurePosixPath

from filelock import FileLock

from sb3_cmzdril.errors import UserError
from sb3_cmzdril.io import PathLike, atomic_path, file_sha256

#: An archived study ``results/NAME`` is the file ``results/NAME`` + this suffix.
SUFFIX = ".tar.xz"
#: Inside an unpacked folder: the archive's digest and the files as unpacked (path -> size, mtime).
STAMP = ".unpacked.json"
#: What a run folder holds besides its records, left out of an archive: checkpoints and kept policies
#: (the models; a record keeps what they scored), the replay buffer, the text log, locks.
NOT_RECORDS: tuple[str, ...] = ("model*.zip", "*.pt", "*.pkl", "log.txt", ".lock", "*.lock")


def archive_of(folder: PathLike) -> Path:
    """The archive that holds ``folder``'s files."""
    folder = Path(folder)
    return folder.with_name(folder.name + SUFFIX)


def materialize(path: PathLike) -> Path:
    """``path``, readable: where it is or lies below an archived study folder, that folder is
    unpacked from its archive (when missing or out of date). Other paths are returned as they are."""
    path = Path(path)
    for folder in (path, *path.parents):
        if folder.name and archive_of(folder).is_file():
            unpack(archive_of(folder), folder)
            break
    return path


def materialize_all(results: PathLike) -> list[Path]:
    """Unpack every archived study in the folder ``results`` and in its plain subfolders (``tuning/``
    keeps one archive per study), where missing or out of date; the folders."""
    archives = [*sorted(Path(results).glob(f"*{SUFFIX}")), *sorted(Path(results).glob(f"*/*{SUFFIX}"))]
    folders = [Path(str(archive)[: -len(SUFFIX)]) for archive in archives]
    for folder in folders:
        unpack(archive_of(folder), folder)
    return folders


def _listing(folder: Path) -> dict[str, list[int]]:
    """Every file below ``folder`` but the stamp: relative path -> [size, mtime in ns]."""
    files = {}
    for path in sorted(folder.rglob("*")):
        if path.is_file() and path.name != STAMP:
            stat = path.stat()
            files[path.relative_to(folder).as_posix()] = [stat.st_size, stat.st_mtime_ns]
    return files


def _read_stamp(folder: Path) -> dict | None:
    try:
        return json.loads((folder / STAMP).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _write_stamp(folder: Path, digest: str) -> None:
    (folder / STAMP).write_text(json.dumps({"archive_sha256": digest, "files": _listing(folder)}), encoding="utf-8")


def _safe_members(tar: tarfile.TarFile, archive: Path) -> list[tarfile.TarInfo]:
    """The archive's members, each a plain file or folder inside the target (UserError otherwise)."""
    members = tar.getmembers()
    for member in members:
        name = Path(member.name)
        if name.is_absolute() or ".." in name.parts or not (member.isfile() or member.isdir()):
            raise UserError(f"{archive}: member {member.name!r} is not a plain file inside the archive's folder")
    return members


def unpack(archive: PathLike, folder: PathLike) -> None:
    """Unpack ``archive`` into ``folder`` unless it already holds that archive's files.

    :raises UserError: ``folder`` exists but was not unpacked from an archive, or holds files that
        were added or changed since (runs that are not packed yet).
    """
    archive, folder = Path(archive), Path(folder)
    digest = file_sha256(archive)
    with FileLock(str(folder.with_name(f".{folder.name}.lock"))):
        stamp = _read_stamp(folder)
        if stamp is not None and stamp.get("archive_sha256") == digest:
            return
        if folder.exists():
            if stamp is None:
                raise UserError(f"{folder} exists and was not unpacked from {archive}: move it away, or pack it "
                                f"(cmzdril-lab pack {folder}) to replace the archive")
            if stamp.get("files") != _listing(folder):
                raise UserError(f"{folder} holds runs added or changed since it was unpacked, and {archive} has "
                                f"changed too: pack them first (cmzdril-lab pack {folder}) or move them away")
        partial = folder.with_name(f".{folder.name}.unpacking-{os.getpid()}")
        shutil.rmtree(partial, ignore_errors=True)
        with tarfile.open(archive, "r:xz") as tar:
            for member in _safe_members(tar, archive):
                target = partial / member.name
                if member.isdir():
                    target.mkdir(parents=True, exist_ok=True)
                    continue
                target.parent.mkdir(parents=True, exist_ok=True)
                source = tar.extractfile(member)
                assert source is not None
                target.write_bytes(source.read())
        _write_stamp(partial, digest)
        if folder.exists():
            shutil.rmtree(folder)
        partial.rename(folder)


def pack(folder: PathLike) -> Path:
    """Write ``folder``'s run records into its archive (sorted, with no times or owners: the same files
    make the same bytes; :data:`NOT_RECORDS` left out) and mark the folder as unpacked from it. Returns
    the archive's path."""
    folder = Path(folder)
    if not folder.is_dir():
        raise UserError(f"not a folder: {folder}")
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:xz", format=tarfile.PAX_FORMAT) as tar:
        for relative in _listing(folder):
            if any(fnmatch.fnmatch(PurePosixPath(relative).name, pattern) for pattern in NOT_RECORDS):
                continue
            data = (folder / relative).read_bytes()
            info = tarfile.TarInfo(relative)
            info.size, info.mode, info.mtime = len(data), 0o644, 0
            tar.addfile(info, io.BytesIO(data))
    archive = archive_of(folder)
    with atomic_path(archive) as tmp:
        tmp.write_bytes(buffer.getvalue())
    _write_stamp(folder, file_sha256(archive))
    return archive


__all__ = ["STAMP", "SUFFIX", "archive_of", "materialize", "materialize_all", "pack", "unpack"]
