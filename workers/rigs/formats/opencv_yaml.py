"""Reading OpenCV FileStorage files (YAML or XML) with cv2.FileStorage: matrices, numbers, string lists."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from workers.rigs.formats.common import FormatError


class Storage:
    """An open FileStorage; `mat`, `number`, `strings` return None for absent keys."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise FormatError(f"{path}: file not found")
        try:
            self._fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        except cv2.error as exc:
            raise FormatError(f"{path}: not a readable OpenCV FileStorage file ({str(exc).strip()[:200]})") from None
        if not self._fs.isOpened():
            raise FormatError(f"{path}: not a readable OpenCV FileStorage file")

    def top_level_keys(self) -> list[str]:
        return list(self._fs.root().keys())

    def has(self, key: str) -> bool:
        return not self._fs.getNode(key).empty()

    def mat(self, key: str) -> np.ndarray | None:
        node = self._fs.getNode(key)
        if node.empty():
            return None
        if node.isSeq():
            return np.array([node.at(i).real() for i in range(node.size())], dtype=np.float64)
        value = node.mat()
        if value is None:
            raise FormatError(f"{self.path}: field '{key}' is not a matrix")
        return np.asarray(value, dtype=np.float64)

    def number(self, key: str) -> float | None:
        node = self._fs.getNode(key)
        if node.empty():
            return None
        if not (node.isReal() or node.isInt()):
            raise FormatError(f"{self.path}: field '{key}' is not a number")
        return node.real()

    def strings(self, key: str) -> list[str] | None:
        node = self._fs.getNode(key)
        if node.empty():
            return None
        if not node.isSeq():
            raise FormatError(f"{self.path}: field '{key}' is not a list")
        # Unquoted numeric names ("- 01") read as numbers; OpenCV 3.4 writers pad lists with "none" entries.
        values = [node.at(i).string() or str(int(node.at(i).real())) for i in range(node.size())]
        return [v for v in values if v != "none"]

    def close(self) -> None:
        self._fs.release()
