"""Trust signals on every result (issue 17): predicted uncertainty, errors, out-of-distribution flag."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

import seqmotion as sm
from seqmotion.cli import main
from seqmotion.core import trust
from seqmotion.core.results import first_of
from seqmotion.models.seq2seq import rollout
from seqmotion.physics.integrator import integrate_covariance, propagate_covariance_reference
from seqmotion.tasks.pancake import data as pancake_data
from seqmotion.tasks.sliding import data as sliding_data


def test_a_sketch_far_longer_than_any_trained_is_flagged_and_fresh_ones_mostly_not(deformer, one_thread):
    long = deformer.deform(pancake_data.straight((0.1, 0.05, 1.0), 2000))
    assert long.out_of_distribution is True and any(r.startswith("length 2000 > 500") for r in long.ood_reasons)
    fresh = pancake_data.position_type(60, np.random.default_rng(11), length=300).states
    batch = deformer.deform(fresh)
    assert batch.out_of_distribution.shape == (60,) and len(batch.ood_reasons) == 60
    assert batch.out_of_distribution.mean() <= 0.1  # measured ≈ 3 % over 400 (benchmarks/results_trust.md)
    short = deformer.deform(pancake_data.straight((0.1, 0.05, 1.0), 40))
    assert short.out_of_distribution and "length 40 < 100" in short.ood_reasons


def test_uncertainty_shapes_and_the_closed_form_equals_the_chunked_propagation(deformer, planner, one_thread):
    sketch = pancake_data.straight((0.1, 0.05, 1.0), 260)
    one, two = deformer.deform(sketch), deformer.deform(np.stack([sketch, sketch]))
    assert one.uncertainty.shape == (260, 3) and two.uncertainty.shape == (2, 260, 3)
    assert np.all(one.uncertainty[0] == 0) and np.all(one.uncertainty >= 0) and one.uncertainty[-1].min() > 0
    np.testing.assert_allclose(two.uncertainty[1], one.uncertainty, rtol=1e-5, atol=1e-9)
    command = sliding_data.mixture(2, np.random.default_rng(3), bspline_prob=0.5, length=700).states
    plan = planner.plan(command)
    assert plan.uncertainty.shape == (2, 700, 2) and planner.uncertainty_names == ("x", "y")
    for model, x in ((deformer, sketch[None]), (planner, command)):
        xt = torch.from_numpy(x)
        with torch.inference_mode():
            z, x0 = model.encode_torch(xt), model.start_state(xt).double()
            _, _, fast = model.rollout_with_std(z, x0, x.shape[1])
            chunked = rollout(model.model, z, x0, model.dynamics(), model.model.num_chunks(x.shape[1]))
        np.testing.assert_allclose(fast, trust.position_std(chunked.outputs["pos_cov"], x.shape[1]), rtol=1e-6,
                                   atol=1e-12)


def test_integrate_covariance_is_eq_2_14_sample_by_sample():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(300, 2, 2))
    s_u = a @ a.transpose(0, 2, 1)
    ref = propagate_covariance_reference(s_u)[1:, :2, :2]
    got = integrate_covariance(torch.from_numpy(s_u)[None]).numpy()[0]
    np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-18)


def test_errors_match_a_direct_computation(deformer, planner, one_thread):
    sketch = pancake_data.position_type(1, np.random.default_rng(5), length=350).states[0]
    r = deformer.deform(sketch)
    gap = np.linalg.norm(r.states[:, :2] - sketch[:, :2], axis=1)
    assert r.errors["shape_rmse_m"] == pytest.approx(np.sqrt((gap**2).mean()))
    assert r.errors["end_position_error_m"] == pytest.approx(gap[-1])
    assert r.errors["end_attitude_error_rad"] == pytest.approx(abs(r.states[-1, 2] - sketch[-1, 2]))
    assert r.errors["end_speed_m_s"] == pytest.approx(np.linalg.norm(r.states[-1, 3:5]))
    assert r.errors["max_violation_rad"] == pytest.approx(r.violation.max())
    command = sliding_data.circle(0.03, 900)
    p = planner.plan(command)
    gap = np.linalg.norm(p.rel_states[:, :2] - command[:, :2], axis=1)
    assert p.errors["tracking_rmse_m"] == pytest.approx(np.sqrt((gap**2).mean()))
    assert p.errors["end_error_m"] == pytest.approx(gap[-1])
    assert p.errors["pan_max_m"] == pytest.approx(np.linalg.norm(p.pan_states[:, :2], axis=1).max())
    travel = np.linalg.norm(command[:, :2], axis=1).max()  # ≈ the 60 mm diameter
    assert p.errors["travel_share"] == pytest.approx(np.linalg.norm(p.rel_states[:, :2], axis=1).max() / travel)


def test_assess_agrees_with_the_result_and_decode_is_not_judged(deformer, one_thread):
    sketch = pancake_data.straight((0.15, -0.05, 2.0), 400)
    r = deformer.deform(sketch)
    a = deformer.assess(sketch, r.states, r.accel, latent=r.latent)
    assert a.errors == pytest.approx(r.errors) and a.out_of_distribution == r.out_of_distribution
    np.testing.assert_allclose(a.uncertainty, r.uncertainty, rtol=1e-6, atol=1e-12)
    errors, flagged, reasons, std = deformer.assess(sketch[None], r.states[None], r.accel[None])
    assert errors["shape_rmse_m"].shape == (1,) and flagged.shape == (1,) and std is None
    with pytest.raises(ValueError, match="need states"):
        deformer.assess(sketch, r.states[:-1], r.accel)
    decoded = deformer.decode(r.latent, r.states[0], 400)
    assert decoded.out_of_distribution is None and decoded.errors is None and decoded.uncertainty.shape == (400, 3)


def test_predicted_uncertainty_tracks_the_realised_error(deformer, one_thread):
    """A learned truth: where the model predicts more spread, its motion strays further from the sketch
    (Spearman 0.90 over 400 held-out sketches in benchmarks/results_trust.md)."""
    rng = np.random.default_rng(21)
    predicted, realised = [], []
    for length in (150, 300, 450):
        r = deformer.deform(pancake_data.position_type(20, rng, length=length).states)
        predicted += list(np.sqrt((np.linalg.norm(r.uncertainty[..., :2], axis=-1) ** 2).mean(axis=-1)))
        realised += list(r.errors["shape_rmse_m"])
    ranks = [np.argsort(np.argsort(v)) for v in (predicted, realised)]
    assert np.corrcoef(*ranks)[0, 1] > 0.6


def test_calibration_ships_with_the_model_and_is_made_on_the_fly_elsewhere(deformer, tmp_path, one_thread):
    shipped = trust.calibration_for(deformer)
    assert shipped.source == trust.TRUST_FILE and shipped.weights_sha256 == deformer.config["weights_sha256"]
    assert shipped.lower["length"] == 100 and shipped.upper["length"] == 500
    assert trust.TrustCalibration.from_dict(shipped.to_dict()).upper == shipped.upper
    copy = sm.load(deformer.save_pretrained(tmp_path / "copy"))
    assert copy.deform(pancake_data.straight((0.1, 0.0, 0.5), 1000)).out_of_distribution
    assert copy.trust_calibration.source == "calibrate" and copy.trust_calibration.n == trust.ON_THE_FLY_N
    stale = {**shipped.to_dict(), "weights_sha256": "0" * 64}
    (tmp_path / "copy" / trust.TRUST_FILE).write_text(json.dumps(stale))
    assert trust.read_calibration(tmp_path / "copy", deformer.config["weights_sha256"]) is None
    path = trust.write_calibration(copy, tmp_path / "copy", n=64)
    assert trust.read_calibration(path.parent, deformer.config["weights_sha256"]).n == 64


@pytest.mark.parametrize("text, match", [("{not json", "not valid JSON"), ("[]", "JSON object"),
                                         ('{"upper": NaN}', "NaN"), ('{"format": "other"}', "not a trust calibration")])
def test_a_missing_calibration_is_none_and_a_corrupt_one_an_error_naming_it(tmp_path, text, match):
    assert trust.read_calibration(tmp_path) is None
    (tmp_path / trust.TRUST_FILE).write_text(text)
    with pytest.raises(ValueError, match=match) as caught:
        trust.read_calibration(tmp_path)
    assert str(tmp_path / trust.TRUST_FILE) in str(caught.value)


def test_first_of_indexes_the_trust_fields():
    from seqmotion.tasks.pancake import DeformResult

    batch = DeformResult(states=np.zeros((2, 3, 6)), accel=np.zeros((2, 2, 3)), violation=np.zeros((2, 2)),
                         psi=np.zeros((2, 2)), latent=np.zeros((2, 4)), uncertainty=np.zeros((2, 3, 3)),
                         errors={"shape_rmse_m": np.array([1.0, 2.0])}, out_of_distribution=np.array([False, True]),
                         ood_reasons=[[], ["length 9 < 100"]])
    one = first_of(batch)
    assert one.errors == {"shape_rmse_m": 1.0} and one.out_of_distribution is False and one.ood_reasons == []


def test_cli_prints_errors_and_warns(tmp_path, capsys, one_thread):
    sketch = tmp_path / "long.csv"
    np.savetxt(sketch, pancake_data.straight((0.1, 0.05, 1.0), 1000), delimiter=",")
    assert main(["deform", "--input", str(sketch), "--output", str(tmp_path / "out.npz")]) == 0
    out = capsys.readouterr().out
    assert "errors: shape_rmse" in out and "predicted std at the end" in out
    assert "warning: the input lies outside what the model was trained on: length 1000 > 500" in out
    saved = np.load(tmp_path / "out.npz")
    assert saved["out_of_distribution"] and "errors.end_position_error_m" in saved.files
    assert main(["plan", "--circle", "0.2", "--length", "3000", "--output", str(tmp_path / "plan.csv")]) == 0
    out = capsys.readouterr().out
    assert "warning: tracking_rmse" in out and "> tolerance 5.0 mm" in out and "length 3000 > 1500" in out
    header = (tmp_path / "plan.csv").read_text().splitlines()[0].split(",")
    assert "std.x" in header and "std.y" in header
    assert main(["plan", "--circle", "0.2", "--length", "3000", "--tolerance", "1", "--output",
                 str(tmp_path / "plan.csv")]) == 0
    assert "warning: tracking_rmse" not in capsys.readouterr().out
