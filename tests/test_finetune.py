"""Fine-tuning: ``train(..., init_from=...)`` / ``seqmotion train --init-from``, the final-stage curriculum, and the
pancake's end terms (``alpha_end``, ``alpha_rest``), which leave the loss untouched at their default 0."""

import math

import numpy as np
import pytest
import torch

import seqmotion as sm
from seqmotion import tasks
from seqmotion.tasks.pancake import PancakeOptions, chapter2_curriculum
from seqmotion.tasks.pancake import data as inputs
from seqmotion.training import checkpoint as ckpt
from seqmotion.training.trainer import step_loss


def _tiny(**options):
    task = tasks.get("pancake")
    config = task.train_config("tiny")
    config.options = task.options(config).replace(**options).to_dict()
    return task, config


def test_final_stage_curriculum_holds_the_schedules_end():
    c = chapter2_curriculum()
    final = {"teacher_forcing_prob": 0.0, "phi_max": math.pi, "accel_type_prob": 0.0}
    assert c.final() == final
    held = c.at_final_stage(20)
    assert held.epochs == 20 and held.at(1) == final and held.at(20, 0.99) == final


def test_init_from_loads_the_weights_strictly_and_records_them(tmp_path):
    torch.set_num_threads(1)
    task, config = _tiny()
    source = tasks.train(config, tmp_path / "a", progress=False, stop_at_step=1)
    _, want = ckpt.read_model(source)

    config.seed, config.lr = 1, 1e-12  # other fresh weights; a step that cannot move them
    run = tasks.train(config, tmp_path / "b", progress=False, stop_at_step=1, init_from=source)
    saved, got = ckpt.read_model(run)
    for name, tensor in want.items():
        torch.testing.assert_close(got[name], tensor, atol=1e-6, rtol=0)
    assert saved["provenance"]["init_from"] == {"path": str(source), "weights_sha256": ckpt.read_config(source)[
        "weights_sha256"]}

    fresh = tasks.train(config, tmp_path / "c", progress=False, stop_at_step=1)  # seed 1, no init: other weights
    assert not torch.allclose(ckpt.read_model(fresh)[1]["head.net.0.weight"], want["head.net.0.weight"])

    with pytest.raises(ValueError, match="model config differs"):  # the shipped small model into a tiny run
        tasks.train(config, tmp_path / "d", progress=False, stop_at_step=1, init_from=sm.pretrained_models()["pancake"])
    with pytest.raises(ValueError, match="no such model"):  # names are resolved by `seqmotion train`
        tasks.train(config, tmp_path / "e", progress=False, stop_at_step=1, init_from="pancake")


def test_end_terms_are_off_by_default_and_leave_the_config_unchanged():
    task, config = _tiny()
    assert "alpha_end" not in config.options and "alpha_rest" not in config.options  # old configs stay identical
    assert PancakeOptions.from_dict(config.options).alpha_rest == 0.0
    torch.manual_seed(0)
    model = task.build_model(config)
    batch = inputs.position_type(4, np.random.default_rng(0), length=(20, 60))
    params = {"teacher_forcing_prob": 0.0, "phi_max": math.pi, "accel_type_prob": 0.0}

    def loss(**options):
        _, cfg = _tiny(**options)
        return step_loss(task, model, batch, params, cfg, torch.Generator().manual_seed(0))

    base, terms = loss()
    zero, _ = loss(alpha_end=0.0, alpha_rest=0.0)
    assert torch.equal(base, zero) and "L_rest" not in terms
    rest, rest_terms = loss(alpha_rest=2.0)
    end, end_terms = loss(alpha_end=3.0)
    assert float((rest - base).detach()) == pytest.approx(2.0 * rest_terms["L_rest"], rel=2e-3)
    assert float((end - base).detach()) == pytest.approx(3.0 * end_terms["L_end"], rel=2e-3)
    assert rest_terms["L_rest"] > 0 and end_terms["L_end"] > 0
