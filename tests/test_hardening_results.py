"""Hardening of two input paths: what a plug-in task's ``sample()`` and ``loss()`` hand the trainer, and what
``sm.load_result`` reads back. Both are refused by name (the task, the method or the array, expected vs got)
instead of ending in a traceback or a plot of arrays that do not belong together."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import seqmotion as sm
from seqmotion.cli import main
from seqmotion.core import registry
from seqmotion.core.results import Motion
from seqmotion.data.trajectories import TrajectoryBatch
from seqmotion.physics.layout import StateLayout
from seqmotion.tasks.pancake import DeformResult
from seqmotion.tasks.pancake.physics import PancakePhysics

TRAY = Path(__file__).resolve().parents[1] / "examples" / "tray" / "src"


# --- a plug-in task's sample() batch and loss --------------------------------------------------------


def _broken_batch(batch: TrajectoryBatch, mode: str) -> TrajectoryBatch:
    """``batch`` spoiled the way ``mode`` says (a plug-in author's slip)."""
    states, lengths = batch.states, batch.lengths
    if mode == "3 of 4 columns":
        return TrajectoryBatch(states[..., :3], lengths)
    if mode == "no batch axis":
        return TrajectoryBatch(states[0], lengths)
    if mode == "lengths past K":
        return TrajectoryBatch(states, lengths + states.shape[1])
    if mode == "lengths of another batch":
        return TrajectoryBatch(states, lengths[:-1])
    if mode == "accel of another length":
        return TrajectoryBatch(states, lengths, accel=np.zeros((len(states), 5, 2)))
    if mode == "extras of another batch":
        return TrajectoryBatch(states, lengths, extras={"mass": np.ones(len(states) + 1)})
    if mode == "bool states":
        return TrajectoryBatch(states > 0, lengths)
    if mode == "a dict":
        return {"states": states, "lengths": lengths}  # type: ignore[return-value]
    return batch


def _broken_loss(loss: torch.Tensor, terms: dict, mode: str) -> object:
    if mode == "loss of shape (3,)":
        return loss * torch.ones(3), terms
    if mode == "loss without the tuple":
        return loss
    if mode == "loss as a float":
        return float(loss.detach()), terms
    if mode == "loss detached from the weights":
        return loss.detach(), terms
    if mode == "terms as a list":
        return loss, list(terms.values())
    if mode == "a term as a tensor":
        return loss, {**terms, "L1": loss}
    return loss, terms


SAMPLE_MODES = {  # mode → what the message must say (the task and method are checked for every one)
    "3 of 4 columns": r"states of shape \(8, \d+, 3\), expected \(8, K, 4\) \(the columns of tray state",
    "no batch axis": r"states of shape \(\d+, 4\), expected \(B, K, 4\)",
    "lengths past K": r"lengths .* between 2 and K = \d+",
    "lengths of another batch": r"lengths of shape \(7,\), expected \(8,\)",
    "accel of another length": r"accel of shape \(8, 5, 2\), expected \(8, \d+, accel_dim\)",
    "extras of another batch": r"extras\['mass'\] of shape \(9,\), expected \(8, \.\.\.\)",
    "bool states": r"states of dtype bool, expected numbers",
    "a dict": r"returned a dict, expected a TrajectoryBatch",
}
LOSS_MODES = {
    "loss of shape (3,)": r"loss of shape \(3,\), expected a scalar",
    "loss without the tuple": r"returned a Tensor, expected \(loss, terms\)",
    "loss as a float": r"loss of type float, expected a scalar torch.Tensor",
    "loss detached from the weights": r"does not depend on the model's weights",
    "terms as a list": r"terms of type list, expected a dict",
    "a term as a tensor": r"terms\['L1'\] of type Tensor, expected a float",
}


@pytest.fixture(scope="module")
def broken_tray():
    """A factory of plug-in tasks (the example tray task with one slip each), registered by hand under their
    own names; everything is forgotten again afterwards."""
    sys.path.insert(0, str(TRAY))
    from seqmotion_tray.task import TrayOptions, TrayTask

    def make(mode: str) -> str:
        class Broken(TrayTask):
            name = "tray_" + "".join(c if c.isalnum() else "_" for c in mode)

            def train_config(self, preset):  # short motions: one step takes a fraction of a second
                config = super().train_config(preset)
                config.task, config.options = self.name, TrayOptions(length=(30, 60), reach=0.03).to_dict()
                return config

            def sample(self, n, rng, params, options):
                return _broken_batch(super().sample(n, rng, params, options), mode)

            def loss(self, *args):
                return _broken_loss(*super().loss(*args), mode)

        registry.register(Broken())
        return Broken.name

    yield make
    sys.path.remove(str(TRAY))
    for module in [m for m in sys.modules if m.split(".")[0] == "seqmotion_tray"]:
        del sys.modules[module]
    registry.refresh()


def _train(name: str, out: Path, capsys) -> tuple[int, str]:
    rc = main(["train", name, "--config", "tiny", "--max-steps", "1", "--out", str(out), "--quiet"])
    return rc, capsys.readouterr().err


@pytest.mark.parametrize("mode", list(SAMPLE_MODES) + list(LOSS_MODES))
def test_a_plug_ins_bad_batch_or_loss_is_refused_by_name(broken_tray, mode, tmp_path, capsys):
    name = broken_tray(mode)
    rc, err = _train(name, tmp_path / "run", capsys)
    method = "sample" if mode in SAMPLE_MODES else "loss"
    assert rc == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    assert err.startswith(f"seqmotion train: error: task {name!r}: {method}() returned "), err
    import re

    assert re.search((SAMPLE_MODES | LOSS_MODES)[mode], err), err
    assert not (tmp_path / "run" / "model.safetensors").exists()


def test_the_plug_ins_good_batch_and_loss_still_train(broken_tray, tmp_path, capsys):
    rc, err = _train(broken_tray("fine"), tmp_path / "run", capsys)
    assert rc == 0, err
    assert (tmp_path / "run" / "model.safetensors").is_file()


# --- sm.load_result: every array against the task's layout and the others --------------------------------


def _deform_result(batch: tuple[int, ...] = (), k: int = 10) -> DeformResult:
    """A small, consistent pancake result (no model needed: shapes are what is checked)."""
    rng = np.random.default_rng(0)
    return DeformResult(
        rng.normal(size=(*batch, k, 6)), rng.normal(size=(*batch, k - 1, 3)),
        rng.normal(size=(*batch, 128)).astype(np.float32), np.zeros((*batch, k - 1)), rng.normal(size=(*batch, k - 1)),
        uncertainty=np.ones((*batch, k, 3)), errors={"shape_rmse_m": np.zeros(batch) if batch else np.float64(0.0)},
        out_of_distribution=np.zeros(batch, bool) if batch else False,
        ood_reasons=[[] for _ in range(batch[0])] if batch else [], exact=np.ones(batch, bool) if batch else True,
        length=np.full(batch, k) if batch else np.int64(k), task="pancake", physics=PancakePhysics(),
    )


def _tampered(path: Path, out: Path, **arrays: np.ndarray) -> Path:
    """The saved result at ``path`` with some arrays replaced (its class and layout kept), written to ``out``."""
    with np.load(path) as saved:
        members = {name: saved[name] for name in saved.files}
    np.savez(out, **{**members, **arrays})
    return out


TAMPERED = {  # what is replaced in a saved single (K = 10) pancake result → what the message must say
    "accel of another length": ({"accel": np.zeros((299, 3))}, r"'accel' has shape \(299, 3\), expected \(9, 3\)"),
    "2-column pancake states": ({"states": np.zeros((10, 2))},
                                r"'states' has shape \(10, 2\), expected \(K, 6\): the columns of pancake state"),
    "bool states": ({"states": np.ones((10, 6), bool)}, r"'states' holds bool, expected floats"),
    "integer accel": ({"accel": np.ones((9, 3), np.int64)}, r"'accel' holds int64, expected floats"),
    "NaN in the states": ({"states": np.full((10, 6), np.nan)}, r"'states' holds NaN or inf"),
    "3 accel columns of 2": ({"accel": np.zeros((9, 2))}, r"'accel' has shape \(9, 2\), expected \(9, 3\)"),
    "one sample": ({"states": np.zeros((1, 6)), "accel": np.zeros((0, 3))}, r"'states' has 1 sample, expected K ≥ 2"),
    "violation of another length": ({"violation": np.zeros(4)}, r"'violation' has shape \(4,\), expected \(9,\)"),
    "uncertainty of 7 fields": ({"uncertainty": np.ones((10, 7))},
                                r"'uncertainty' has shape \(10, 7\), expected \(10, 3\)"),
    "negative uncertainty": ({"uncertainty": -np.ones((10, 3))}, r"'uncertainty' holds negative values or NaN"),
    "a batch of latents": ({"latent": np.zeros((2, 128), np.float32)},
                           r"'latent' has shape \(2, 128\), expected \(L,\)"),
    "an error per trajectory": ({"errors.shape_rmse_m": np.zeros(3)},
                                r"'errors.shape_rmse_m' has shape \(3,\), expected \(\)"),
    "a length past K": ({"length": np.int64(500)}, r"'length' is 500, expected 2 … K = 10"),
    "out_of_distribution per trajectory": ({"out_of_distribution": np.zeros(2, bool)},
                                           r"'out_of_distribution' has shape \(2,\), expected \(\)"),
}


@pytest.mark.parametrize("case", list(TAMPERED))
def test_load_result_refuses_arrays_that_do_not_belong_together(case, tmp_path):
    path = _deform_result().save(tmp_path / "r.npz")
    arrays, message = TAMPERED[case]
    bad = _tampered(path, tmp_path / "bad.npz", **arrays)
    with pytest.raises(ValueError, match=message) as refused:
        sm.load_result(bad)
    assert str(bad) in str(refused.value) and "\n" not in str(refused.value)


def test_load_result_checks_a_batch_against_its_batch_axis(tmp_path):
    path = _deform_result((2,)).save(tmp_path / "r.npz")
    assert sm.load_result(path).states.shape == (2, 10, 6)
    for arrays, message in (
        ({"accel": np.zeros((3, 9, 3))}, r"'accel' has shape \(3, 9, 3\), expected \(2, 9, 3\)"),
        ({"latent": np.zeros((3, 128), np.float32)}, r"'latent' has shape \(3, 128\), expected \(2, L\)"),
        ({"violation": np.zeros((2, 10))}, r"'violation' has shape \(2, 10\), expected \(2, 9\)"),
        ({"exact": np.ones(3, bool)}, r"'exact' has shape \(3,\), expected \(2,\)"),
        ({"length": np.array([10, 1])}, r"'length' is 1, expected 2 … K = 10"),
    ):
        with pytest.raises(ValueError, match=message):
            sm.load_result(_tampered(path, tmp_path / "bad.npz", **arrays))


def test_load_result_reads_a_plug_ins_layout_and_still_loads_what_is_saved(tmp_path):
    class Plate:  # a task registered by hand: its layouts are all load_result needs
        name = "hr_plate"
        state_layout = StateLayout(("x", "y", "v_x", "v_y"), ("m", "m", "m/s", "m/s"), "plate state")
        accel_layout = StateLayout(("a_x", "a_y"), ("m/s²", "m/s²"), "plate acceleration")

        def load(self, directory: object) -> None:
            raise NotImplementedError

    registry.register(Plate())
    try:
        good = Motion(np.zeros((10, 4)), np.zeros((9, 2)), None, np.zeros(9), task="hr_plate")
        back = sm.load_result(good.save(tmp_path / "good.npz"))
        assert back.states.shape == (10, 4) and back.task == "hr_plate"
        wrong = Motion(np.zeros((10, 6)), np.zeros((9, 2)), None, task="hr_plate").save(tmp_path / "wrong.npz")
        with pytest.raises(ValueError, match=r"'states' has shape \(10, 6\), expected \(K, 4\): the columns of "
                                             r"plate state"):
            sm.load_result(wrong)
    finally:
        registry.refresh()
    # every consistent result still loads: single and batched, and one without a task (no layout to read)
    for result in (_deform_result(), _deform_result((3,), k=2),
                   Motion(np.zeros((5, 7)), np.zeros((4, 1)), None)):
        back = sm.load_result(result.save(tmp_path / "ok.npz"))
        np.testing.assert_array_equal(back.states, result.states)
