"""Deployment: a trained model's encoder and decoder step as ONNX, run by onnxruntime and NumPy.

>>> import seqmotion as sm
>>> sm.deploy.export_onnx(sm.load_pretrained("pancake"), "pancake-onnx")    # seqmotion export-onnx pancake pancake-onnx
>>> gen = sm.deploy.OnnxStepper("pancake-onnx", sketch)                      # model.generator(sketch)'s interface
>>> u = gen.step(); u = gen.step(measured)

The folder is self-contained: its ``onnx_stepper.py`` runs with NumPy and onnxruntime alone. It is
written whole (a re-export swaps it in) and sealed: ``contract.json`` carries the SHA-256 of each
graph and of itself, and loading refuses an edited, invalid or mixed bundle (``bundle.py``).
Needs the optional extra ``pip install 'seqmotion[deploy]'`` (onnx, onnxruntime).
"""

from .export import export_onnx
from .onnx_stepper import OnnxModel, OnnxStepper

__all__ = ["OnnxModel", "OnnxStepper", "export_onnx"]
