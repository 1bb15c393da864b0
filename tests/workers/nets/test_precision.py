"""bfloat16 only where the device computes it natively (workers.nets.mvnet.native_bf16)."""

from __future__ import annotations

import torch

import workers.nets.mvnet as mvnet
from workers.nets.mvnet import UNet3d


def _outputs(monkeypatch, native: bool) -> tuple[torch.Tensor, torch.Tensor]:
    monkeypatch.setattr(mvnet, "native_bf16", lambda device_type: native)
    torch.manual_seed(0)
    net = UNet3d(4, (8, 8), 3, norm="batch").eval()
    x = torch.randn(1, 4, 8, 8, 8)
    with torch.no_grad():
        return net(x, bf16=True), net(x, bf16=False)


def test_bf16_request_runs_float32_where_bf16_is_not_native(monkeypatch):
    asked, plain = _outputs(monkeypatch, native=False)
    torch.testing.assert_close(asked, plain, rtol=0, atol=0)


def test_bf16_request_runs_bfloat16_where_native(monkeypatch):
    asked, plain = _outputs(monkeypatch, native=True)
    assert asked.dtype == torch.float32  # outputs stay float32
    assert not torch.equal(asked, plain)  # but the convolutions ran in bfloat16
    torch.testing.assert_close(asked, plain, rtol=0.1, atol=0.1)


def test_native_bf16_answers_for_every_device_type():
    assert isinstance(mvnet.native_bf16("cpu"), bool)
    assert mvnet.native_bf16("cuda") == (torch.cuda.is_available() and torch.cuda.is_bf16_supported())
    assert mvnet.native_bf16("meta") is False
