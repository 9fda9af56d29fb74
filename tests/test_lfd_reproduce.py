"""`seqmotion reproduce ch5` end to end on tiny data and tiny models: every table and figure is written."""

from __future__ import annotations

import functools
import json
import shutil

import pytest

pytest.importorskip("seqmotion.lfd.env.pushing")
from seqmotion.lfd import evaluation, train  # noqa: E402
from seqmotion.lfd.data import dataset  # noqa: E402
from seqmotion.reproduce import ch5  # noqa: E402


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """Short demonstrations (1 per position and set), and tiny policies in every slot ch5 needs."""
    out = tmp_path_factory.mktemp("ch5")
    one = {name: 1 for name in dataset.CHAPTER_SETS}
    dataset.collect(out / "data", seed=0, duration=0.6, per_position=one, progress=False)
    dataset.collect(
        out / "data_unseen",
        ["pairs_default"],
        seed=ch5.UNSEEN_SEED_OFFSET,
        duration=0.6,
        per_position={"pairs_default": 1},
        progress=False,
    )
    tiny = out / "tiny"
    fast = train.SeqAETraining(epochs=1, batch_size=4)
    train.train(
        out / "data",
        tiny,
        "tiny",
        ("proposed", "end_to_end"),
        ("default", "position1", "position2"),
        seed=0,
        seqae_settings=fast,
        e2e_settings=fast,
        cnn_settings=train.CNNTraining(epochs=1),
        progress=False,
        successful_only=False,
    )
    for preset_name, method, camera in ch5._needed():
        shutil.copytree(tiny / f"{method}_{camera}", out / "models" / preset_name / f"{method}_{camera}")
    return out


def test_ch5_quick(workdir, monkeypatch):
    short = functools.partial(evaluation.evaluate, duration=0.5)  # 0.5-s trials: the pipeline, not the numbers
    monkeypatch.setattr(evaluation, "evaluate", short)
    summary = ch5.run(workdir, quick=True, seed=0)
    assert summary["main_preset"] == train.DEFAULT_PRESET and summary["trials_per_position"] == 1
    assert set(summary["table5_2"]) == {"proposed", "end_to_end"}
    for row in summary["table5_2"].values():
        assert set(row) == set(ch5.PRESET_NAMES)
        assert all(r["n_trials"] == 6 and 0.0 <= r["success_rate"] <= 1.0 for r in row.values())
    assert set(summary["table5_3"]) == set(ch5.CAMERA_NAMES)
    assert set(summary["snapshots"]) == {"end_to_end", "proposed"}
    for name in (
        "table5_2.md",
        "table5_2.json",
        "table5_3.md",
        "table5_3.json",
        "fig5_9_success.png",
        "fig5_11_latent_pca.png",
        "fig5_10_snapshots_proposed.png",
        "fig5_10_snapshots_end_to_end.png",
        "summary.json",
        "evaluations.json",
    ):
        assert (workdir / name).stat().st_size > 0, name
    table = (workdir / "table5_2.md").read_text()
    assert "56.7%" in table and "6.7%" in table  # the dissertation's numbers beside ours
    pca = json.loads((workdir / "fig5_11_latent_pca.json").read_text())
    assert len(pca["proposed"]["pc"]) == 6 and sorted(pca["proposed"]["position_index"]) == list(range(6))
    for ratios in pca["explained_variance"].values():
        assert len(ratios) == 2 and 0.0 <= sum(ratios) <= 1.0 + 1e-9
