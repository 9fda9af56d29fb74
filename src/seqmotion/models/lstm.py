"""Layer-normalised LSTM (Ba, Kiros & Hinton 2016 — ref. [46]) as used in chs. 2–4.

One cell step, with LN(·) a layer norm over the 4H gate pre-activations::

    i, f, o, g = LN(W_x x) + LN(W_h h) + b
    c' = σ(f) ⊙ c + σ(i) ⊙ tanh(g)
    h' = σ(o) ⊙ tanh(LN(c'))

A :class:`StackedLSTM` runs L such cells on top of each other for one time step; its state
is a tuple of ``(h, c)`` pairs, one per layer.
"""

from __future__ import annotations

import torch
from torch import nn

LSTMState = tuple[tuple[torch.Tensor, torch.Tensor], ...]


class LayerNormLSTMCell(nn.Module):
    """One layer-normalised LSTM cell.

    Args:
        input_size: features of ``x``.
        hidden_size: H, size of ``h`` and ``c``.
    """

    def __init__(self, input_size: int, hidden_size: int) -> None:
        super().__init__()
        self.hidden_size = hidden_size
        self.input_proj = nn.Linear(input_size, 4 * hidden_size, bias=False)
        self.hidden_proj = nn.Linear(hidden_size, 4 * hidden_size, bias=False)
        self.ln_input = nn.LayerNorm(4 * hidden_size)
        self.ln_hidden = nn.LayerNorm(4 * hidden_size, bias=False)
        self.ln_cell = nn.LayerNorm(hidden_size)
        with torch.no_grad():  # a forget-gate bias of 1 keeps memories early in training
            self.ln_input.bias.zero_()
            self.ln_input.bias[hidden_size : 2 * hidden_size] = 1.0

    def forward(
        self, x: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor]
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``x`` (B, input_size), ``state = (h, c)`` each (B, H) → new ``(h, c)``."""
        h, c = state
        gates = self.ln_input(self.input_proj(x)) + self.ln_hidden(self.hidden_proj(h))
        i, f, o, g = gates.chunk(4, dim=-1)
        c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(g)
        h = torch.sigmoid(o) * torch.tanh(self.ln_cell(c))
        return h, c


class StackedLSTM(nn.Module):
    """L layer-normalised LSTM cells stacked; one call advances all layers by one step."""

    def __init__(self, input_size: int, hidden_size: int, num_layers: int) -> None:
        super().__init__()
        if num_layers < 1 or hidden_size < 1:
            raise ValueError("num_layers and hidden_size must be positive")
        self.hidden_size, self.num_layers = hidden_size, num_layers
        sizes = [input_size] + [hidden_size] * (num_layers - 1)
        self.cells = nn.ModuleList(LayerNormLSTMCell(s, hidden_size) for s in sizes)

    def zero_state(self, batch: int, like: torch.Tensor) -> LSTMState:
        z = like.new_zeros(batch, self.hidden_size)
        return tuple((z, z) for _ in self.cells)

    def forward(self, x: torch.Tensor, state: LSTMState) -> tuple[torch.Tensor, LSTMState]:
        """``x`` (B, input_size) → top-layer output (B, H) and the new state."""
        new_state = []
        for cell, layer_state in zip(self.cells, state, strict=True):
            h, c = cell(x, layer_state)
            new_state.append((h, c))
            x = h
        return x, tuple(new_state)
