"""The on-disk capture format: records, a validating reader and a writer (docs/capture-format.md)."""

from workers.capture.reader import load_frame_images, load_frame_masks, load_ground_truth, read_capture
from workers.capture.schema import (
    FORMAT_NAME,
    FORMAT_VERSION,
    Capture,
    CaptureError,
    FrameRef,
    GroundTruth,
    HandModelInfo,
    Sequence,
    Subject,
    frame_name,
)
from workers.capture.writer import write_capture_header, write_frame, write_sequence

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "Capture",
    "CaptureError",
    "FrameRef",
    "GroundTruth",
    "HandModelInfo",
    "Sequence",
    "Subject",
    "frame_name",
    "load_frame_images",
    "load_frame_masks",
    "load_ground_truth",
    "read_capture",
    "write_capture_header",
    "write_frame",
    "write_sequence",
]
