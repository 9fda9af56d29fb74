"""Recurrent cells and the chunked sequence-to-sequence model."""

from .lstm import LayerNormLSTMCell, StackedLSTM
from .seq2seq import ChunkDynamics, ChunkedSeq2Seq, Rollout, Seq2SeqConfig, rollout

__all__ = ["ChunkDynamics", "ChunkedSeq2Seq", "LayerNormLSTMCell", "Rollout", "Seq2SeqConfig", "StackedLSTM", "rollout"]
