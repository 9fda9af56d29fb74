"""Deployment: a trained model's encoder, decoder step and own dynamics as ONNX, run by onnxruntime and NumPy.

>>> import seqmotion as sm
>>> sm.deploy.export_onnx(sm.load_pretrained("pancake"), "pancake-onnx")    # seqmotion export-onnx pancake pancake-onnx
>>> gen = sm.deploy.OnnxStepper("pancake-onnx", sketch)                      # model.generator(sketch)'s interface
>>> u = gen.step(); u = gen.step(measured)
>>> plan = sm.deploy.OnnxStepper("sliding-onnx", command, physics={"mu": 0.8})  # at another friction
>>> n = gen.step_into(measured, out)                                          # a control loop's call: no array made
>>> sm.deploy.export_c(sm.load_pretrained("pancake"), "pancake-c")            # seqmotion export-c pancake pancake-c

The task's dynamics are a graph of the bundle, traced from the PyTorch code the model trains with,
so any task's physics deploys (a plug-in's too) and runs at other values of the physics fields the
graph reads. The folder is self-contained: its ``onnx_stepper.py`` runs with NumPy and onnxruntime alone. It is
written whole (a re-export swaps it in) and sealed: ``contract.json`` carries the SHA-256 of each
graph and of itself, and loading refuses an edited, invalid or mixed bundle (``bundle.py``). The seal detects
corruption, not intent (anyone can re-seal a bundle): loading also checks each graph against the contract and
bounds what it may run, so load only bundles you trust.
``export_c`` writes the decoder step, the dynamics and the online generator as dependency-free C99
(:mod:`seqmotion.deploy.c_export`); :mod:`seqmotion.deploy.realtime` is the measured 1 kHz loop recipe
(``seqmotion bench-step``, ``docs/realtime.md``).
Needs the optional extra ``pip install 'seqmotion[deploy]'`` (onnx, onnxruntime).
"""

from .c_export import export_c
from .export import export_onnx
from .onnx_stepper import OnnxModel, OnnxStepper

__all__ = ["OnnxModel", "OnnxStepper", "export_c", "export_onnx"]
