"""Weight-only int8 inference for large recurrent models on CPUs.

Generating one trajectory steps the decoder once per chunk with a batch of one, so every step
streams all LSTM weights from memory: a 2 × 1024 decoder reads ~67 MB of float32 per chunk and
is limited by memory bandwidth, not arithmetic. Storing the big matrices as int8 with one
float scale per output row (symmetric, per-channel) cuts that traffic by 4×. On CPUs with
bf16 instructions PyTorch's packed kernel ``torch._weight_int8pack_mm`` computes the product
directly from int8 weights; elsewhere the weights are dequantised once (same numbers, float32
speed).

The rounding error is small (≈ 0.5 % relative per product, mostly from rounding the inputs to
bf16): measure it on your model before trusting a quantised one for anything but speed —
``benchmarks/bench_sliding.py`` reports the plan difference it makes.
"""

from __future__ import annotations

import copy

import torch
from torch import nn

from ..errors import check_number


def _packed_kernel_available() -> bool:
    if not hasattr(torch, "_weight_int8pack_mm"):  # a private op: guard every use
        return False
    try:  # the kernel exists in the build but may not support this CPU
        w = torch.ones(8, 32, dtype=torch.int8)
        torch._weight_int8pack_mm(torch.ones(1, 32, dtype=torch.bfloat16), w, torch.ones(8, dtype=torch.bfloat16))
    except RuntimeError:
        return False
    return True


class Int8Linear(nn.Module):
    """``nn.Linear`` with int8 weights and per-output-row scales (inference only).

    Args:
        linear: the float layer to quantise; its weight ``(out, in)`` becomes
            ``round(W / s)`` in int8 with ``s = max|W_row| / 127``.
    """

    packed = _packed_kernel_available()

    def __init__(self, linear: nn.Linear) -> None:
        super().__init__()
        weight = linear.weight.detach().float()
        scale = weight.abs().amax(dim=1).clamp_min(1e-12) / 127.0
        self.in_features, self.out_features = linear.in_features, linear.out_features
        self.register_buffer("weight_int8", torch.round(weight / scale[:, None]).to(torch.int8))
        self.register_buffer("scale", scale)
        self.register_buffer("scale_bf16", scale.to(torch.bfloat16))
        self.register_buffer("bias", None if linear.bias is None else linear.bias.detach().float().clone())
        # the packed kernel reads inputs in blocks of 16 features (other widths give garbage)
        self.use_packed = self.packed and self.in_features % 16 == 0
        dequantised = None if self.use_packed else self.weight_int8.float() * scale[:, None]
        self.register_buffer("weight_dequantised", dequantised)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        lead = x.shape[:-1]
        flat = x.reshape(-1, self.in_features)
        if self.use_packed and flat.device.type == "cpu":
            out = torch._weight_int8pack_mm(flat.to(torch.bfloat16), self.weight_int8, self.scale_bf16).float()
            if self.bias is not None:
                out = out + self.bias
        else:
            weight = self.weight_dequantised
            if weight is None:
                weight = self.weight_int8.float() * self.scale[:, None]
            out = nn.functional.linear(flat.float(), weight, self.bias)
        return out.reshape(*lead, self.out_features).to(x.dtype)


def quantize_int8(model: nn.Module, min_features: int = 256) -> nn.Module:
    """A copy of ``model`` with every ``nn.Linear`` of ≥ ``min_features`` inputs and outputs in int8.

    Small layers stay in float32: they cost little and quantising them buys nothing. The copy is
    for inference (no gradients flow to int8 weights); the original is untouched.
    """
    check_number("min_features", min_features, minimum=1)
    quantized = copy.deepcopy(model).eval()
    for name, module in list(quantized.named_modules()):
        for child_name, child in list(module.named_children()):
            big = isinstance(child, nn.Linear) and min(child.in_features, child.out_features) >= min_features
            if big:
                setattr(module, child_name, Int8Linear(child))
        del name
    for p in quantized.parameters():
        p.requires_grad_(False)
    return quantized
