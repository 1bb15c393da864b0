"""File storage behind a small interface: local disk now; a shared or object store can replace it by
implementing the same four methods. Keys are relative POSIX paths, e.g. 'captures/3/cam0/000012.png'."""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
from pathlib import Path, PurePosixPath
from typing import Protocol

from backend.services.errors import InvalidInputError, NotFoundError


class Storage(Protocol):
    def put_bytes(self, key: str, data: bytes) -> None: ...
    def put_file(self, key: str, source: Path) -> None: ...
    def get_bytes(self, key: str) -> bytes: ...
    def etag(self, key: str) -> str: ...
    def mtime_ns(self, key: str) -> int: ...


def _check_key(key: str) -> PurePosixPath:
    path = PurePosixPath(key)
    if path.is_absolute() or ".." in path.parts or not path.parts:
        raise InvalidInputError(f"invalid storage key {key!r}")
    return path


class LocalDiskStorage:
    """Files under one root directory; writes are atomic (temporary file + rename)."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)

    def _path(self, key: str) -> Path:
        return self.root.joinpath(*_check_key(key).parts)

    def local_path(self, key: str) -> Path:
        """The file behind `key` (workers read images as files; distributed mode shares this folder)."""
        return self._path(key)

    def put_bytes(self, key: str, data: bytes) -> None:
        path = self._path(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, delete=False) as handle:
            handle.write(data)
        os.replace(handle.name, path)

    def put_file(self, key: str, source: Path) -> None:
        path = self._path(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".part")
        shutil.copyfile(source, tmp)
        os.replace(tmp, path)

    def get_bytes(self, key: str) -> bytes:
        try:
            return self._path(key).read_bytes()
        except FileNotFoundError as exc:
            raise NotFoundError(f"file {key!r} is missing from storage") from exc

    def etag(self, key: str) -> str:
        try:
            stat = self._path(key).stat()
        except FileNotFoundError as exc:
            raise NotFoundError(f"file {key!r} is missing from storage") from exc
        return hashlib.sha1(f"{key}:{stat.st_size}:{stat.st_mtime_ns}".encode()).hexdigest()[:20]

    def mtime_ns(self, key: str) -> int:
        """When the file behind `key` was last written, ns since the epoch (NotFoundError when missing)."""
        try:
            return self._path(key).stat().st_mtime_ns
        except FileNotFoundError as exc:
            raise NotFoundError(f"file {key!r} is missing from storage") from exc
