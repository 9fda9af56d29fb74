"""The ACT convergence campaign (``benchmarks/peers/act/campaign.py``): its scheduler, and the verdict it reports.

The campaign's real jobs need LeRobot's venv and hours; what is checked here, with its processes faked, is the
part that decides which worker runs what: two workers side by side evaluate every checkpoint exactly once, never
run one training's slices at the same time, and a training never waits for its own checkpoints' evaluations. Then
that what RESULTS_lfd.md says of who leads is what ``results_lfd_act.json`` holds, and that every ACT row called
converged met the stop rule.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import re
import threading
import time
import types
from pathlib import Path

import pytest

CAMPAIGN = Path(__file__).resolve().parents[1] / "benchmarks" / "peers" / "act" / "campaign.py"


@pytest.fixture()
def campaign(monkeypatch: pytest.MonkeyPatch):
    spec = importlib.util.spec_from_file_location("act_campaign_under_test", CAMPAIGN)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    monkeypatch.setattr(module, "results", lambda args: None)
    monkeypatch.setattr(module, "_tree", lambda: {})
    monkeypatch.setattr(module, "_write_json", lambda path, payload: path.write_text(json.dumps(payload)))
    monkeypatch.setattr(module, "log", lambda msg: None)
    monkeypatch.setattr(module.signal, "signal", lambda *a: None)  # signal handlers belong to the main thread
    monkeypatch.setattr(module, "time", types.SimpleNamespace(sleep=lambda s: time.sleep(0.02)))
    return module


def fake_jobs(events: list[tuple], final_step: int, train_s: float, eval_s: float):
    """``_call`` stand-in: a training slice writes its checkpoint and log, an evaluation its JSON."""
    guard = threading.Lock()

    def call(cmd: list[str]) -> int:
        worker = threading.current_thread().name
        if cmd[1].endswith("train_act.py"):
            out = Path(cmd[cmd.index("--out") + 1])
            step = min(int(cmd[cmd.index("--stop-at") + 1]), final_step)
            with guard:
                events.append((worker, "train start", out.name, step, time.monotonic()))
            time.sleep(train_s)
            weights = out / "checkpoints" / f"{step:06d}" / "pretrained_model"
            weights.mkdir(parents=True, exist_ok=True)
            (weights / "model.safetensors").write_text("weights")
            done = step >= final_step
            (out / "train_log.json").write_text(json.dumps(
                {"steps": step, "finished": done, "stop_reason": "patience" if done else None}))
            with guard:
                events.append((worker, "train end", out.name, step, time.monotonic()))
        else:
            model = Path(cmd[2])
            time.sleep(eval_s)
            Path(cmd[cmd.index("--json") + 1]).write_text(json.dumps({"successes": 1}))
            with guard:
                events.append((worker, "eval", model.parents[2].name, int(model.parent.name), time.monotonic()))
        return 0

    return call


def run_two_workers(campaign, root: Path, monkeypatch: pytest.MonkeyPatch, plan: list[tuple[int, int]],
                    final_step: int, train_s: float, eval_s: float) -> list[tuple]:
    """Two campaign workers (threads) on ``plan`` with faked jobs; the events they ran, in order."""
    (root / "choice.json").write_text(json.dumps({"chosen": "small", "config": []}))
    args = argparse.Namespace(root=root, data=root, compare_steps=1, compare_val_every=1, plan=plan,
                              min_steps=final_step - 1, patience=2, cap=40, val_every=1, eval_every=2, trials=1,
                              eval_seed=0, val_spec="successful:9-9")
    events: list[tuple] = []
    monkeypatch.setattr(campaign, "_call", fake_jobs(events, final_step, train_s, eval_s))
    workers = [threading.Thread(target=campaign.run, args=(args,), name=f"w{i}") for i in range(2)]
    for w in workers:
        w.start()
        time.sleep(0.01)
    for w in workers:
        w.join(timeout=60)
    assert not any(w.is_alive() for w in workers)
    return events


def test_two_workers_evaluate_every_checkpoint_once_while_training_goes_on(campaign, tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    # evaluations take longer than slices, as on the machine (6-20 min against 15 min per 2,000 steps)
    events = run_two_workers(campaign, tmp_path, monkeypatch, [(100, 0), (25, 0)], final_step=7, train_s=0.05,
                             eval_s=0.15)
    evals = sorted((e[2], e[3]) for e in events if e[1] == "eval")
    # every multiple of --eval-every and the final step, each exactly once
    assert evals == sorted((f"hard_{n}_0", s) for n in (100, 25) for s in (2, 4, 6, 7))
    for name in ("hard_100_0", "hard_25_0"):
        slices = [e for e in events if e[1].startswith("train") and e[2] == name]
        # a training's slices never overlap (one holder of its lock at a time) and reach the end in order
        assert [e[1] for e in slices] == ["train start", "train end"] * 4
        assert [e[3] for e in slices if e[1] == "train end"] == [2, 4, 6, 7]
    # the first training ran its four slices back to back (0.2 s) while its evaluations (0.6 s in all) ran beside
    first = [e for e in events if e[2] == "hard_100_0"]
    trained = max(e[4] for e in first if e[1] == "train end")
    assert any(e[1] == "eval" and e[4] > trained for e in first)
    assert trained - min(e[4] for e in first) < 0.15 * 4


def test_a_worker_waits_for_checkpoints_of_a_training_another_holds(campaign, tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    events = run_two_workers(campaign, tmp_path, monkeypatch, [(10, 1)], final_step=4, train_s=0.1, eval_s=0.02)
    assert sorted(e[3] for e in events if e[1] == "eval") == [2, 4]
    assert [e[3] for e in events if e[1] == "train end"] == [2, 4]
    # the worker without the training did not leave: it waited and evaluated step 2 while step 4 was training
    eval_2 = next(e for e in events if e[1] == "eval" and e[3] == 2)
    slice_4 = next(e for e in events if e[1] == "train end" and e[3] == 4)
    assert eval_2[0] != slice_4[0] and eval_2[4] < slice_4[4]


# --- the verdict RESULTS_lfd.md states is the one results_lfd_act.json holds ---------------------------------------

RESULTS_LFD = Path(__file__).resolve().parents[1] / "benchmarks" / "RESULTS_lfd.md"
CURVE = Path(__file__).resolve().parents[1] / "benchmarks" / "results_lfd_act.json"
WHO_LEADS_COLUMNS = ("feedback", "proposed", "end_to_end", "act")


def _pooled(rows: list[dict], method: str, demonstrations: int) -> tuple[int, int, list[int]]:
    """Successes and trials of ``method`` at ``demonstrations``, its training seeds pooled; ACT's runs trained to
    convergence only (they carry the stop rule's reason)."""
    mine = [r for r in rows if r["method"] == method and r["demonstrations"] == demonstrations
            and (method != "act" or r.get("stop_reason"))]
    return sum(r["successes"] for r in mine), sum(r["trials"] for r in mine), sorted(r["seed"] for r in mine)


def test_the_who_leads_table_is_the_curve_files_numbers() -> None:
    from seqmotion.lfd.evaluation import wilson_interval

    rows = json.loads(CURVE.read_text())["rows"]
    text = RESULTS_LFD.read_text()
    table = text[text.index("**Who leads**"):]
    table = table[:table.index("\n\n", table.index("| demonstrations |"))]
    lines = [ln for ln in table.splitlines() if re.match(r"\| \d+ \|", ln)]
    assert lines, "RESULTS_lfd.md has no who-leads table"
    for line in lines:
        cells = [c.strip() for c in line.strip("|").split("|")]
        demonstrations = int(cells[0])
        stated = {}
        for method, cell in zip(WHO_LEADS_COLUMNS, cells[1:], strict=True):
            m = re.search(r"(\d+) %\D*\((\d+)–(\d+) %\)", cell)
            assert m, f"{demonstrations} demonstrations, {method}: no 'P % (L–H %)' in {cell!r}"
            stated[method] = tuple(int(x) for x in m.groups())
        for method, (rate, low, high) in stated.items():
            successes, trials, seeds = _pooled(rows, method, demonstrations)
            assert trials, f"{method} at {demonstrations}: no rows in results_lfd_act.json"
            wl, wh = wilson_interval(successes, trials)
            assert (rate, low, high) == (round(100 * successes / trials), round(100 * wl), round(100 * wh)), (
                f"{method} at {demonstrations}: RESULTS_lfd.md says {rate} % ({low}–{high} %), the curve's "
                f"{successes} / {trials} (seeds {seeds}) gives another")
        # the leader is the one the table marks in bold
        leader = max(stated, key=lambda k: stated[k][0])
        assert "**" in cells[1 + WHO_LEADS_COLUMNS.index(leader)]


def test_every_converged_act_row_meets_the_stop_rule() -> None:
    """At least 10,000 steps, and stopped by the validation loss, not by the step cap."""
    rows = [r for r in json.loads(CURVE.read_text())["rows"] if r["method"] == "act" and r.get("stop_reason")]
    assert rows
    for r in rows:
        assert r["train_steps"] >= 10_000 and r["stop_reason"] == "patience", r["model"]
        best = min(v["val_l1"] for v in r["val_log"] if v["step"] > 0)
        late = [v["val_l1"] for v in r["val_log"] if v["step"] > r["train_steps"] - 2000]
        # levelled: no validation in the last 2,000 steps improved on the best before them
        assert min(late) >= best, r["model"]
        assert [c["step"] for c in r["curve"]][-1] == r["train_steps"]
