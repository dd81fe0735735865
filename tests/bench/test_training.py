"""The training kit every learned plugin's ``train.py`` stands on: staged, resumable, reproducible."""

from __future__ import annotations

import datetime
import json
from dataclasses import dataclass

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from ssga_bench.training import TrainingRun, cosine_lr, export_checkpoint, poly_lr, training_main, training_provenance  # noqa: E402
from ssga_core import InputError  # noqa: E402


@dataclass(frozen=True)
class Config:
    stages: tuple[tuple[int, int, int], ...] = ((4, 5, 3), (8, 3, 2))
    lr: tuple[float, ...] = (0.1, 0.01)
    checkpoint_every: int = 2
    seed: int = 0


class Interrupted(Exception):
    pass


class Run(TrainingRun):
    """Least squares on random features; each stage sees the inputs at its own width."""

    metrics = ("loss", "stage_width")
    stop_after: int | None = None

    def begin_stage(self, stage, data):
        self.begun = [*getattr(self, "begun", []), stage]
        return data[:, : self.config.stages[stage][0]]

    def learning_rate(self, stage, step, steps):
        return cosine_lr(self.config.lr[stage], step, steps)

    def train_step(self, net, optimizer, stage, data, rng):
        if self.stop_after is not None:
            if self.stop_after == 0:
                raise Interrupted
            self.stop_after -= 1
        idx = rng.choice(len(data), self.config.stages[stage][2], replace=False)
        x = torch.zeros(len(idx), 8)
        x[:, : data.shape[1]] = torch.from_numpy(data[idx])
        loss = (net(x).squeeze(1) - x.sum(1)).square().mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        return loss.item(), data.shape[1]


def fresh_net() -> torch.nn.Module:
    torch.manual_seed(0)
    return torch.nn.Linear(8, 1)


DATA = np.random.default_rng(1).normal(size=(20, 8)).astype(np.float32)


def train(out, stop_after=None):
    run = Run(Config(), out)
    run.stop_after = stop_after
    net = fresh_net()
    return run, *run.train(net, torch.optim.SGD(net.parameters(), lr=0.0), DATA)


def test_an_interrupted_run_resumes_to_exactly_the_uninterrupted_result(tmp_path, capsys):
    _, straight, straight_history = train(tmp_path / "straight")
    with pytest.raises(Interrupted):
        train(tmp_path / "resumed", stop_after=6)  # stage 2's first step: the last checkpoint was stage 1's end
    run, resumed, history = train(tmp_path / "resumed")
    assert "resuming at stage 2, step 0" in capsys.readouterr().out
    assert run.begun == [1], "a finished stage is not prepared again"
    assert torch.equal(straight.weight, resumed.weight) and torch.equal(straight.bias, resumed.bias)
    assert history == straight_history
    assert [(int(h[0]), int(h[1]), int(h[3])) for h in history] == [(0, s, 4) for s in range(1, 6)] + [(1, s, 8) for s in range(1, 4)]
    assert not resumed.training, "the network comes back in eval mode"


def test_the_progress_line_names_every_metric_with_rate_and_eta(tmp_path, capsys):
    train(tmp_path / "run")
    lines = [line for line in capsys.readouterr().out.splitlines() if "step" in line]
    assert len(lines) == 5  # steps 2, 4, 5 of stage 1; 2, 3 of stage 2
    assert "stage 1/2 (4 px) step 2/5: loss " in lines[0] and ", stage_width 4, lr 0.09" in lines[0]
    assert "images/s, stage ends in" in lines[0]


def test_figures_summarise_each_stage_and_the_time_spent(tmp_path):
    run, _, history = train(tmp_path / "run")
    figures = run.figures(history)
    assert [s["size"] for s in figures["loss"]] == [4, 8] and figures["loss"][1]["batch"] == 2
    assert figures["loss"][0]["first"]["stage_width"] == 4 and figures["loss"][1]["last"]["stage_width"] == 8
    first_loss = np.mean([h[2] for h in history if h[0] == 0][: figures["loss"][0]["window"]])
    assert figures["loss"][0]["first"]["loss"] == round(float(first_loss), 5)
    assert set(figures["seconds"]) == {"stage1", "stage2"} and figures["training_seconds"] >= 0


def test_a_folder_of_another_config_is_refused(tmp_path):
    Run(Config(), tmp_path / "run")
    with pytest.raises(InputError, match="holds a run of another config"):
        Run(Config(seed=1), tmp_path / "run")


def test_learning_rate_schedules():
    assert cosine_lr(1.0, 0, 10) == 1.0 and cosine_lr(1.0, 10, 10) == pytest.approx(0.1)
    assert cosine_lr(1.0, 5, 10) == pytest.approx(0.55)
    assert poly_lr(2.0, 0, 10) == 2.0 and poly_lr(2.0, 5, 10) == pytest.approx(2.0 * 0.5**0.9)


def test_export_writes_the_checkpoint_and_a_record_of_its_bytes(tmp_path):
    started = datetime.datetime(2026, 1, 2, 3, 4, 5, tzinfo=datetime.timezone.utc)
    provenance = training_provenance("a test network", "some.module", ["--out", "x y"], started, Config(), {"loss": []}, train_seeds=[1])
    assert provenance["command"] == "python -m some.module --out 'x y'" and provenance["date"] == "2026-01-02T03:04:05+00:00"
    assert provenance["config"]["stages"] == [[4, 5, 3], [8, 3, 2]] and provenance["train_seeds"] == [1]
    path = export_checkpoint(tmp_path / "w", "net", {"state_dict": fresh_net().state_dict()}, provenance)
    checkpoint = torch.load(path, weights_only=True)
    assert checkpoint["provenance"]["what"] == "a test network" and set(checkpoint["state_dict"]) == {"weight", "bias"}
    record = json.loads((tmp_path / "w" / "net.json").read_text())
    assert record["bytes"] == path.stat().st_size and record["file"] == "net.pt" and len(record["sha256"]) == 64


def test_the_command_line_reports_an_ssga_error_in_one_line(tmp_path, capsys):
    calls = []

    def run_training(config, out, export, *, evaluate_heldout, argv):
        calls.append((out, export, evaluate_heldout))
        raise InputError(f"{out}: nothing to train on")

    code = training_main("some.module", "Train it.\n\nMore.", run_training, Config(), ["--out", str(tmp_path), "--no-eval"], exports="net.pt", default_export=lambda out: out / "weights")
    assert code == 1 and calls == [(tmp_path, tmp_path / "weights", False)]
    assert capsys.readouterr().err.strip() == f"error: {tmp_path}: nothing to train on"


# --------------------------------------------------------------------------- the whole command


@dataclass(frozen=True)
class CommandConfig(Config):
    train_seeds: tuple[int, ...] = (7,)


class Command(Run):
    """The least-squares run as a whole training command: each hook records that it ran."""

    module = "some.train"
    what = "a least-squares test network"
    export_name = "net"

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.called: list[str] = []

    def training_data(self):
        self.called.append("data")
        return DATA

    def initial(self, data):
        self.called.append("initial")
        return fresh_net()

    def network(self):
        return torch.nn.Linear(8, 1)

    def optimizer(self, net):
        return torch.optim.SGD(net.parameters(), lr=0.0)  # as train() below; the schedule sets the rate

    def after_training(self, net, data):
        self.called.append("after")
        return {"after": 1}

    def heldout_figures(self, init, net):
        self.called.append("heldout")
        assert not init.training and not net.training
        return {"init": init.bias.item(), "trained": net.bias.item()}

    def provenance_extra(self, net):
        return {"train_seeds": [7]}


def test_the_command_trains_from_the_initialisation_and_exports_it_with_its_provenance(tmp_path):
    run = Command(CommandConfig(), tmp_path / "run")
    path = run.command(tmp_path / "out", argv=["--out", "run"])
    assert run.called == ["data", "initial", "after", "heldout"]
    _, net, _ = train(tmp_path / "plain")  # the same loop from the same initialisation, by hand
    checkpoint = torch.load(path, weights_only=True)
    assert torch.equal(checkpoint["state_dict"]["weight"], net.weight), "training starts from the initialisation"
    provenance = checkpoint["provenance"]
    assert provenance["what"] == "a least-squares test network" and provenance["command"] == "python -m some.train --out run"
    assert provenance["figures"]["after"] == 1 and provenance["figures"]["heldout"]["init"] == fresh_net().bias.item()
    assert provenance["train_seeds"] == [7] and json.loads((tmp_path / "out" / "net.json").read_text())["sha256"]


def test_without_heldout_figures_the_command_skips_them(tmp_path):
    run = Command(CommandConfig(), tmp_path / "run")
    path = run.command(tmp_path / "out", evaluate_heldout=False, argv=[])
    assert "heldout" not in run.called and "heldout" not in torch.load(path, weights_only=True)["provenance"]["figures"]


# --------------------------------------------------------------------------- the evaluation command


def test_the_evaluation_command_scores_each_weights_file_on_views_made_once(tmp_path, capsys):
    from ssga_bench.training import evaluation_main

    made, scored = [], []

    def held_out(args):
        made.append(args.views)
        return list(range(args.views))

    def measure(weights, views, args):
        scored.append(weights)
        return {"views": len(views), "weights": weights}

    argv = ["--weights", "a.pt", "--weights", "b.pt", "--views", "3", "--json", str(tmp_path / "f.json")]
    code = evaluation_main("some.evaluate", "Score it.", argv, held_out=held_out, measure=measure, add_arguments=lambda p: p.add_argument("--views", type=int))
    assert code == 0 and made == [3] and scored == ["a.pt", "b.pt"]
    printed = json.loads(capsys.readouterr().out)
    assert printed == {"a.pt": {"views": 3, "weights": "a.pt"}, "b.pt": {"views": 3, "weights": "b.pt"}}
    assert json.loads((tmp_path / "f.json").read_text()) == printed
    assert evaluation_main("some.evaluate", "Score it.", [], held_out=lambda a: [], measure=measure) == 0
    assert scored[-1] is None, "no --weights: the packaged ones"


def test_the_evaluation_command_reports_an_ssga_error_in_one_line(capsys):
    from ssga_bench.training import evaluation_main

    def measure(weights, views, args):
        raise InputError(f"weights {weights!r}: no such file")

    assert evaluation_main("some.evaluate", "Score it.", ["--weights", "x.pt"], held_out=lambda a: [], measure=measure) == 1
    assert capsys.readouterr().err.strip().splitlines()[-1] == "error: weights 'x.pt': no such file"
