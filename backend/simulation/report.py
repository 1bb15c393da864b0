"""PNG plots of a bootstrap simulation: dataset growth by stream, and accuracy, per round."""

from __future__ import annotations

from pathlib import Path
from typing import Any

STREAM_COLOURS = {"annotated": "#4c72b0", "manual": "#55a868", "heuristic": "#dd8452"}


def write_plots(summary: dict[str, Any], out_dir: Path) -> dict[str, str]:
    """Write growth.png and accuracy.png into `out_dir`; returns name -> path."""
    # deferred: matplotlib (its Agg backend chosen before pyplot loads) only when plots are written
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    rounds = summary["rounds"]
    labels = [f"D{r['index']}" for r in rounds]
    x = list(range(len(rounds)))

    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    bottom = [0.0] * len(rounds)
    for stream, colour in STREAM_COLOURS.items():
        values = [r["added"][stream] for r in rounds]
        ax.bar(x, values, bottom=bottom, color=colour, label=f"added: {stream}")
        bottom = [b + v for b, v in zip(bottom, values, strict=True)]
    ax.plot(x, [r["dataset_size"] for r in rounds], "k.-", label="|D_i|")
    ax.set_xticks(x, labels)
    ax.set_ylabel("samples")
    ax.set_title("Dataset growth per round")
    hours = ax.twinx()
    hours.plot(x, [r["human_hours_cumulative"] for r in rounds], "--", color="#8172b3", label="human hours")
    hours.set_ylabel("human hours (cumulative)")
    hours.set_ylim(bottom=0)
    lines, names = ax.get_legend_handles_labels()
    more, more_names = hours.get_legend_handles_labels()
    ax.legend(lines + more, names + more_names, loc="upper left", fontsize=8)
    fig.tight_layout()
    growth = out_dir / "growth.png"
    fig.savefig(growth)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)

    def series(key: str) -> list[float]:
        return [float("nan") if r[key] is None else r[key] for r in rounds]

    ax.plot(x, series("accepted_vertex_mm"), "o-", label="accepted set: mean vertex error")
    ax.plot(x, series("added_vertex_mm"), "s--", label="added this round: mean vertex error")
    ax.plot(x, series("mvnet_keypoint_mm"), "^-", label="MVNet: mean keypoint error")
    ax.set_xticks(x, labels)
    ax.set_ylabel("mm against ground truth")
    ax.set_ylim(bottom=0)
    ax.set_title("Accuracy per round")
    ax.legend(fontsize=8)
    fig.tight_layout()
    accuracy = out_dir / "accuracy.png"
    fig.savefig(accuracy)
    plt.close(fig)
    return {"growth": str(growth), "accuracy": str(accuracy)}
