"""Versioned checkpoints: one folder per bootstrap round, one file per network, with metadata.

Layout (docs/networks.md):
    <root>/round-003/mvnet.pt          final weights + metadata (what the worker tasks load)
    <root>/round-003/mvnet.json        the same metadata, readable without torch
    <root>/round-003/mvnet.partial.pt  weights + optimiser state while training (resume)
A checkpoint records its network kind, configuration (and its architecture digest), training samples,
metrics, seed, steps and training seconds; loading it into another configuration fails clearly.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any, Literal

import torch

from workers.nets.configs import HandSegNetConfig, MVNetConfig, config_digest
from workers.nets.handsegnet import HandSegNet
from workers.nets.mvnet import MVNet

FORMAT_VERSION = 1
NetKind = Literal["mvnet", "handsegnet"]


class CheckpointError(ValueError):
    """A checkpoint is missing, unreadable, or does not fit the requested network or configuration."""


def round_dir(root: Path | str, round_index: int) -> Path:
    """The folder of one bootstrap round's checkpoints: <root>/round-NNN."""
    if round_index < 0:
        raise ValueError(f"round_index must be >= 0, got {round_index}")
    return Path(root) / f"round-{round_index:03d}"


def checkpoint_path(checkpoint_dir: Path | str, kind: NetKind, partial: bool = False) -> Path:
    return Path(checkpoint_dir) / f"{kind}{'.partial' if partial else ''}.pt"


def build_metadata(kind: NetKind, config: MVNetConfig | HandSegNetConfig, *, config_name: str, seed: int,
                   sample_ids: list[str] | tuple[str, ...], steps: int, train_seconds: float,
                   metrics: dict[str, Any] | None = None, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    return {
        "format_version": FORMAT_VERSION,
        "kind": kind,
        "config_name": config_name,
        "config": asdict(config),
        "config_digest": config_digest(config),
        "seed": seed,
        "training_samples": list(sample_ids),
        "num_training_samples": len(sample_ids),
        "steps": steps,
        "train_seconds": round(train_seconds, 3),
        "metrics": metrics or {},
        "torch": str(torch.__version__),
        "saved_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        **(extra or {}),
    }


def save_checkpoint(path: Path, model: torch.nn.Module, metadata: dict[str, Any],
                    optimizer: torch.optim.Optimizer | None = None) -> Path:
    """Write atomically (temporary file + rename); a JSON sidecar beside final checkpoints."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {"metadata": metadata, "model": {k: v.detach().cpu() for k, v in model.state_dict().items()}}
    if optimizer is not None:
        state["optimizer"] = optimizer.state_dict()
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(state, tmp)
    os.replace(tmp, path)
    if not path.name.endswith(".partial.pt"):
        path.with_suffix(".json").write_text(json.dumps(metadata, indent=1))
    return path


def read_checkpoint(path: Path | str) -> dict[str, Any]:
    """The raw checkpoint dict {"metadata", "model", ["optimizer"]} (CheckpointError if unreadable)."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: checkpoint not found")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many kinds for a corrupt file
        raise CheckpointError(f"{path}: unreadable checkpoint ({exc})") from None
    if not isinstance(state, dict) or "metadata" not in state or "model" not in state:
        raise CheckpointError(f"{path}: not a handloop checkpoint (no metadata / model)")
    if state["metadata"].get("format_version") != FORMAT_VERSION:
        raise CheckpointError(f"{path}: format version {state['metadata'].get('format_version')} "
                              f"(this handloop reads {FORMAT_VERSION})")
    return state


def check_compatible(metadata: dict[str, Any], kind: NetKind, config: MVNetConfig | HandSegNetConfig,
                     where: Path | str) -> None:
    """Raise CheckpointError when the checkpoint's network kind or architecture differs from `config`."""
    if metadata.get("kind") != kind:
        raise CheckpointError(f"{where}: a {metadata.get('kind')} checkpoint, not {kind}")
    if metadata.get("config_digest") != config_digest(config):
        raise CheckpointError(
            f"{where}: checkpoint of configuration {metadata.get('config_name')!r} (architecture "
            f"{metadata.get('config_digest')}) does not fit the requested configuration (architecture "
            f"{config_digest(config)}); train a new one or load it with its own configuration")


def previous_checkpoint(root: Path | str, kind: NetKind, config: MVNetConfig | HandSegNetConfig,
                        before_round: int) -> Path | None:
    """The final checkpoint of `kind` from the latest round before `before_round` under `root` whose
    architecture fits `config` (read from the JSON sidecars, without torch), or None. Checkpoints of another
    architecture or unreadable sidecars are skipped (a warm start must not fail a round)."""
    root = Path(root)
    if not root.is_dir():
        return None
    digest = config_digest(config)
    indexed = [(int(p.name[6:]), p) for p in root.glob("round-*") if p.name[6:].isdigit()]
    for _, folder in sorted((i, p) for i, p in indexed if i < before_round)[::-1]:
        path = checkpoint_path(folder, kind)
        try:
            meta = json.loads(path.with_suffix(".json").read_text())
        except (OSError, ValueError):
            continue
        if path.is_file() and meta.get("kind") == kind and meta.get("config_digest") == digest:
            return path
    return None


def load_model(path: Path | str, kind: NetKind, config: MVNetConfig | HandSegNetConfig | None = None,
               device: torch.device | str = "cpu") -> tuple[torch.nn.Module, dict[str, Any]]:
    """Load a network and its metadata.

    Args:
        path: a .pt checkpoint.
        kind: "mvnet" or "handsegnet".
        config: the expected configuration; None = the one stored in the checkpoint.
        device: where to put the model.
    Returns:
        (model in eval mode, metadata).
    """

    state = read_checkpoint(path)
    meta = state["metadata"]
    stored_cls = MVNetConfig if kind == "mvnet" else HandSegNetConfig
    if config is None:
        if meta.get("kind") != kind:
            raise CheckpointError(f"{path}: a {meta.get('kind')} checkpoint, not {kind}")
        config = stored_cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in meta["config"].items()})
    check_compatible(meta, kind, config, path)
    model = MVNet(config) if kind == "mvnet" else HandSegNet(config)
    try:
        model.load_state_dict(state["model"])
    except RuntimeError as exc:
        raise CheckpointError(f"{path}: weights do not fit the configuration ({exc})") from None
    return model.to(device).eval(), meta
