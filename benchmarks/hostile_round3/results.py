"""Hostile attempts for two input paths: a plug-in task's sample()/loss() shapes (11) and sm.load_result (14).

Each snippet runs after benchmarks/hostile.py's PRELUDE in a fresh interpreter and an empty temporary folder.
"""

from __future__ import annotations

# A plug-in task written into the cwd and registered through a fake distribution (as defect 8's attempts do):
# a planar point mass, four state columns, whose sample() keeps WIDTH of them and whose loss() is per
# trajectory (shape (3,) for its batch of 3) when VECTOR.
_PLUGIN = '''
import torch
from seqmotion.tasks import Task, TaskOptions
from seqmotion.data.trajectories import TrajectoryBatch, draw_lengths, path_states
from seqmotion.models.seq2seq import Seq2SeqConfig
from seqmotion.physics.integrator import DT, DoubleIntegratorDynamics
from seqmotion.physics.layout import StateLayout
from seqmotion.training.config import TrainConfig
from seqmotion.training.curriculum import Curriculum
from seqmotion.training.losses import encode_and_rollout

WIDTH, VECTOR = {width}, {vector}
STATE = StateLayout(("x", "y", "v_x", "v_y"), ("m", "m", "m/s", "m/s"), "plate state")
ACCEL = StateLayout(("a_x", "a_y"), ("m/s²", "m/s²"), "plate acceleration")


class Plate(Task):
    name = "plate"
    input_layout = state_layout = STATE
    accel_layout = ACCEL

    def train_config(self, preset):
        model = Seq2SeqConfig(encoder_input_dim=4, decoder_input_dim=4, output_dim=2, chunk=10, layers=1, hidden=8,
                              correlated_pairs=[], encoder_input_scale=[1.0] * 4, decoder_input_scale=[1.0] * 4,
                              output_scale=[1.0, 1.0])
        return TrainConfig(task=self.name, preset=preset, model=model.to_dict(),
                           curriculum=Curriculum(epochs=1, initial={{}}).to_dict(), batches_per_epoch=2,
                           batch_size=3, options=TaskOptions().to_dict())

    def sample(self, n, rng, params, options):
        lengths = draw_lengths(rng, n, (30, 50))
        waypoints = rng.uniform(-0.05, 0.05, size=(n, 3, 2))
        waypoints[:, 0] = 0.0
        return TrajectoryBatch(path_states(waypoints, lengths, DT)[..., :WIDTH], lengths)

    def loss(self, model, batch, dynamics, params, options, generator):
        states, k = batch.states, batch.states.shape[1]
        out = encode_and_rollout(model, states, batch.lengths, states[:, 0], dynamics, teacher=states,
                                 teacher_forcing_prob=1.0, generator=generator)
        per_trajectory = ((out.states[:, :k] - states) ** 2).mean(dim=(1, 2))
        return (per_trajectory if VECTOR else per_trajectory.mean()), {{}}

    def dynamics(self, options, physics):
        return DoubleIntegratorDynamics(2, DT)


TASK = Plate()
'''

_TRAIN = """
Path("plate.py").write_text({source!r})
info = Path("plate-0.1.dist-info"); info.mkdir()
(info / "METADATA").write_text("Metadata-Version: 2.1\\nName: plate\\nVersion: 0.1\\n")
(info / "entry_points.txt").write_text("[seqmotion.tasks]\\nplate = plate:TASK\\n")
sys.path.insert(0, os.getcwd())
from seqmotion.core import registry
registry.refresh()
rc, err = cli("train", "plate", "--config", "tiny", "--max-steps", "1", "--out", "runs/p", "--quiet")
named = all(part in err for part in {parts!r})
held(rc == 2 and err.count("\\n") == 1 and "Traceback" not in err and named
     and not Path("runs/p/model.safetensors").exists(), f"rc {{rc}}: {{err[-300:]}}")
"""

# a saved pancake result with some arrays replaced (its class and layout kept): load_result must refuse it by
# array name and shapes (before, it loaded, and .plot() drew it)
_TAMPER = """
result = sm.load_pretrained("pancake").deform(sketches.straight((0.1, 0.0, 2.0), 300))
with np.load(result.save("r.npz")) as saved:
    arrays = {{name: saved[name] for name in saved.files}}
{edit}
np.savez("bad.npz", **arrays)
message = refused(sm.load_result, "bad.npz")
held(message is not None and "bad.npz" in message and "\\n" not in message
     and all(part in message for part in {parts!r}), str(message))
"""

ATTEMPTS: dict[int, list[tuple[str, str]]] = {
    11: [
        ("plug-in sample() returns 3 of 4 state columns",
         _TRAIN.format(source=_PLUGIN.format(width=3, vector=False),
                       parts=["'plate'", "sample()", "(3, ", ", 3)", "expected (3, K, 4)"])),
        ("plug-in loss() of shape (3,)",
         _TRAIN.format(source=_PLUGIN.format(width=4, vector=True), parts=["'plate'", "loss()", "(3,)", "scalar"])),
    ],
    14: [
        ("result: states (10, 6) with accel (299, 3)",
         _TAMPER.format(edit='arrays["states"] = arrays["states"][:10]', parts=["'accel'", "(299, 3)", "(9, 3)"])),
        ("result: 2-column pancake states",
         _TAMPER.format(edit='arrays["states"] = arrays["states"][:, :2]',
                        parts=["'states'", "(300, 2)", "(K, 6)", "pancake state"])),
        ("result: bool states",
         _TAMPER.format(edit='arrays["states"] = arrays["states"] > 0', parts=["'states'", "bool", "floats"])),
    ],
}
