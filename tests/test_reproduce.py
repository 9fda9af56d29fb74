"""The chapter reproductions run end to end (quick mode, tiny models) and write what they promise."""

import json

import numpy as np
import pytest

from seqmotion import tasks
from seqmotion.reproduce import ch2, ch3, ch4
from seqmotion.tasks import train


@pytest.fixture(scope="module")
def pancake_run(tmp_path_factory):
    run = tmp_path_factory.mktemp("pancake")
    train(tasks.get("pancake").train_config("tiny"), run, progress=False)
    return run


def test_ch2_quick(pancake_run, tmp_path, monkeypatch):
    monkeypatch.setattr(ch2, "robot", lambda deformer, out: {"robot": "not run in tests"})
    results = ch2.run(tmp_path, model=str(pancake_run), quick=True)
    for name in ("fig2_5_deformation.png", "fig2_6_psi.png", "fig2_7_deformation_amount.png", "table2_heldout.md"):
        assert (tmp_path / name).stat().st_size > 0
    held = results["heldout"]
    assert held["n"] == 50 and 0.0 <= held["output"]["feasible_share"] <= 1.0
    assert held["input"]["shape_rmse_D"] == 0.0  # the inputs are the reference
    assert json.loads((tmp_path / "results.json").read_text())["heldout"]["n"] == 50


def test_ch4_quick(pancake_run, tmp_path, monkeypatch):
    monkeypatch.setattr(ch4, "robot", lambda states, out, mu: {"robot": "not run in tests"})
    real_peer = ch4.peer
    monkeypatch.setattr(ch4, "peer", lambda deformer, targets: real_peer(deformer, targets[:1]))
    zero = {"one_trajectory_s": 0.0, "batch_of_27_s": 0.0}
    monkeypatch.setattr(ch4, "timing", lambda deformer: {"case": {"lm": zero, "line search": zero}})
    summary = ch4.run(tmp_path, model=str(pancake_run), quick=True)
    assert set(summary["methods"]) == set(ch4.METHODS)
    for method in ("lm", "line search"):  # these never increase the objective, so they cannot diverge
        assert set(summary["methods"][method]) == set(ch4.CASES)
        for case in summary["methods"][method].values():
            assert len(case["mean_j1_by_update"]) == 21
            assert case["mean_j1_by_update"][-1] <= case["mean_j1_by_update"][0]
    # the peer table, side by side on one target: exact=True (latent LM + polish, even from a tiny model)
    # and the strong IPOPT peer both reach J1 ≤ 1e-9 with the cone kept to 1e-6 rad
    (row,) = summary["peer"]
    assert row["exact"] and row["exact_j1"] <= 1e-9 and row["exact_max_fc"] <= 1e-6
    assert row["ipopt_exact"] and row["ipopt_status"] == "Solve_Succeeded"
    assert row["exact_seconds"] > 0 and row["ipopt_seconds"] > 0 and np.isfinite(row["default_j1_update_5"])
    assert "exact=True 1/1, IPOPT 1/1" in (tmp_path / "table4_peer.md").read_text()
    for name in ("fig4_2_objective.png", "fig4_6_end_rmse.png", "fig4_8_j2_velocity.png", "fig4_9_j2_psi.png",
                 "fig4_3_theta_-pi.png", "table4_end_rmse.md", "j2_trajectory.npz"):
        assert (tmp_path / name).stat().st_size > 0
    assert {"update_0", "update_10", "update_20", "update_20 + polish", "dissertation_eta_100_final_J2"} == set(
        summary["j2"])
    polished = summary["j2"]["update_20 + polish"]["terms"]  # the exact polish meets every term of J2
    assert set(polished) == {"end position band", "end attitude band", "velocity limits", "friction cone"}
    assert all(term["met"] for term in polished.values())


def test_ch3_quick(tmp_path, monkeypatch):
    runs = tmp_path / "runs"
    task = tasks.get("sliding")
    for variant in "ABC":
        config = task.apply_variant(task.train_config("tiny"), variant)
        train(config, runs / variant, progress=False)
    monkeypatch.setattr(ch3, "LENGTH", 150)
    monkeypatch.setattr(ch3, "robot", lambda models, command, out: {"robot": "not run in tests"})
    study = ch3.run(tmp_path / "out", model=str(runs), quick=True)
    assert set(study["models"]) == {"A", "B", "C"}
    for res in study["models"].values():
        assert len(res["rmse_mm"]) == len(ch3.FRICTION_GRID) and res["worst_over_best"] >= 1.0
    assert study["still_pan_rmse_mm"] > 0
    for q in study["qualitative"].values():
        assert q["rmse_mm"] > 0 and q["object_travel_share"] >= 0 and q["pan_max_m"] >= 0
    for name in ("fig3_7_paths.png", "fig3_10_friction.png", "table3_friction.md", "table3_range.md",
                 "table3_qualitative.md"):
        assert (tmp_path / "out" / name).stat().st_size > 0
