"""tests/support/real_sized.py: an upscaled capture is reused only when whole."""

from __future__ import annotations

from pathlib import Path

from tests.support import real_sized
from tests.support.real_sized import upscaled_capture
from workers.capture import read_capture
from workers.synth.generator import generate_capture
from workers.synth.plan import SynthConfig


def test_a_partial_capture_is_written_again_and_a_whole_one_reused(tmp_path: Path) -> None:
    generate_capture(tmp_path / "small", SynthConfig(num_sequences=1, frames_per_sequence=1, seed=3, width_px=96),
                     workers=1)
    out = upscaled_capture(tmp_path / "small", tmp_path / "big", width=256, working_width_px=128)
    assert [c.width for c in read_capture(out).cameras] == [256] * 8
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temporary folder left
    image = next(out.rglob("*.jpg"))
    image.write_bytes(b"")  # what an interrupted or concurrent writer leaves: a file not written yet
    assert upscaled_capture(tmp_path / "small", tmp_path / "big", width=256, working_width_px=128) == out
    assert read_capture(out).cameras[0].width == 256  # the image's header read again
    written = image.stat().st_mtime_ns
    upscaled_capture(tmp_path / "small", tmp_path / "big", width=256, working_width_px=128)
    assert image.stat().st_mtime_ns == written  # a whole capture is reused as it is


def test_a_writer_that_finds_the_capture_written_meanwhile_keeps_that_one(tmp_path: Path, monkeypatch) -> None:
    generate_capture(tmp_path / "small", SynthConfig(num_sequences=1, frames_per_sequence=1, seed=3, width_px=96),
                     workers=1)
    write = real_sized._write_upscaled

    def write_while_another_finishes(capture, out, width, working_width_px):
        assert not (tmp_path / "big").exists()  # never the target itself while it is written
        write(capture, tmp_path / "big", width, working_width_px)  # the other writer, done first
        (tmp_path / "big" / "winner").write_text("")
        write(capture, out, width, working_width_px)

    monkeypatch.setattr(real_sized, "_write_upscaled", write_while_another_finishes)
    out = upscaled_capture(tmp_path / "small", tmp_path / "big", width=256, working_width_px=128)
    assert (out / "winner").exists() and read_capture(out).cameras[0].width == 256
    assert sorted(p.name for p in tmp_path.iterdir()) == ["big", "small"]
