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

from ..errors import check_number

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
        # in training, tanh(g) = 2 σ(2g) - 1: the gates' pre-activations scaled by 1 (i, f, o) and 2 (g) go
        # through one sigmoid (PyTorch's CPU tanh runs ~6x slower per element than its sigmoid; agrees to 2e-7)
        scale = torch.ones(4 * hidden_size)
        scale[3 * hidden_size :] = 2.0
        self.register_buffer("gate_scale", scale, persistent=False)

    def forward(
        self, x: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor]
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``x`` (B, input_size), ``state = (h, c)`` each (B, H) → new ``(h, c)``."""
        return self.step_projected(self.project_input(x), state)

    def project_input(self, x: torch.Tensor) -> torch.Tensor:
        """``LN(W_x x)`` for inputs of any leading shape: done once for a whole sequence when known."""
        return self.ln_input(self.input_proj(x))

    def step_projected(
        self, gates_x: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor]
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """One step given the projected input ``LN(W_x x)`` (B, 4H)."""
        h, c = state
        gates = gates_x + self.ln_hidden(self.hidden_proj(h))
        if self.training:  # tanh through the sigmoid (to 2e-7, fewer and faster kernels)
            i, f, o, g = torch.sigmoid(gates * self.gate_scale).chunk(4, dim=-1)  # g = σ(2g) here
            c = f * c + i * (2 * g - 1)
            h = o * _tanh(self.ln_cell(c))
        else:  # inference (and export): exactly the plain cell, so trained models' outputs stay what they were
            # split by the constant H, not chunk(4): a traced chunk computes its sizes from the tensor's shape
            # at run time (12 more graph nodes per step that onnxruntime runs one by one); the same views
            i, f, o, g = gates.split(self.hidden_size, dim=-1)
            c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(g)
            h = torch.sigmoid(o) * torch.tanh(self.ln_cell(c))
        return h, c


def _tanh(x: torch.Tensor) -> torch.Tensor:
    """``tanh x = 2 σ(2x) - 1`` (to 2e-7; several times faster than ``torch.tanh`` on the CPU)."""
    return 2 * torch.sigmoid(2 * x) - 1


class StackedLSTM(nn.Module):
    """L layer-normalised LSTM cells stacked; one call advances all layers by one step."""

    def __init__(self, input_size: int, hidden_size: int, num_layers: int) -> None:
        super().__init__()
        check_number("num_layers", num_layers, minimum=1, integer=True)
        check_number("hidden_size", hidden_size, minimum=1, integer=True)
        self.hidden_size, self.num_layers = hidden_size, num_layers
        sizes = [input_size] + [hidden_size] * (num_layers - 1)
        self.cells = nn.ModuleList(LayerNormLSTMCell(s, hidden_size) for s in sizes)

    def run_packed(self, x: torch.Tensor, sizes: list[int]) -> LSTMState:
        """Run sequences of different lengths, packed, from a zero state; return each one's final state.

        The rows of a batch sorted longest first, step by step: ``x`` ``(sum(sizes), input_size)`` holds
        step 0's inputs of the first ``sizes[0]`` sequences, then step 1's of the first ``sizes[1]``, …
        (``sizes`` non-increasing, as ``torch.nn.utils.rnn.PackedSequence`` orders them). A sequence that
        has ended is not computed on: at batch size 256 with lengths spread evenly this skips about a
        third of the encoder's work. Returns the final ``(h, c)`` per layer, ``(sizes[0], H)`` each, in
        the sorted order: to float rounding, what a step-by-step run freezing each state at its end gives.
        """
        if any(a < b for a, b in zip(sizes, sizes[1:], strict=False)) or not sizes or sizes[-1] < 1:
            raise ValueError(f"packed batch sizes must be positive and non-increasing, got {sizes}")
        final = []
        for cell in self.cells:
            steps = cell.project_input(x).split(sizes)  # one matrix product for all steps of the layer
            h = c = x.new_zeros(sizes[0], self.hidden_size)
            outputs: list[torch.Tensor] = []
            done_h: list[torch.Tensor] = []  # final states of sequences that ended, latest step first
            done_c: list[torch.Tensor] = []
            for t, (gates_x, size) in enumerate(zip(steps, sizes, strict=True)):
                if t > 0 and size < h.shape[0]:  # the last rows' sequences ended at step t - 1
                    h, h_done = h.split([size, h.shape[0] - size])
                    c, c_done = c.split([size, c.shape[0] - size])
                    done_h.insert(0, h_done)
                    done_c.insert(0, c_done)
                h, c = cell.step_projected(gates_x, (h, c))
                outputs.append(h)
            final.append((torch.cat([h, *done_h]), torch.cat([c, *done_c])))
            x = torch.cat(outputs)
        return tuple(final)

    def forward(self, x: torch.Tensor, state: LSTMState) -> tuple[torch.Tensor, LSTMState]:
        """``x`` (B, input_size) → top-layer output (B, H) and the new state."""
        new_state = []
        for cell, layer_state in zip(self.cells, state, strict=True):
            h, c = cell(x, layer_state)
            new_state.append((h, c))
            x = h
        return x, tuple(new_state)
