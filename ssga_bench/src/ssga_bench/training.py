"""What every learned plugin's training command shares, so each ``train.py`` holds only its own data, loss and figures.

A training command (``python -m ssga_<plugin>.train --out RUN [--export DIR]``) trains
in *stages* of growing image size, each a fixed number of optimiser steps, and must
survive interruption: run it again and it goes on from its last checkpoint, drawing
the batches an uninterrupted run would have drawn. :class:`TrainingRun` is that
loop; a plugin subclasses it with four hooks::

    class Run(TrainingRun):
        metrics = ("loss", "accuracy")             # what train_step returns, in order

        def begin_stage(self, stage, data):        # optional: e.g. resize the views once per stage
            return resized(data, self.config.stages[stage][0])

        def learning_rate(self, stage, step, steps):   # optional: the default is lr[stage]
            return poly_lr(self.config.lr[stage], step, steps)

        def train_step(self, net, optimizer, stage, data, rng):
            ...one optimiser step on a batch drawn with rng...
            return loss, accuracy

    net, history = Run(config, out).train(net, optimizer, data)

The config is a frozen dataclass with ``stages`` (``(size, steps, batch, ...)``
tuples), ``lr`` (one per stage), ``checkpoint_every`` and ``seed``; :func:`config_json` is
what a run folder and the exported weights record of it.

The whole command is :meth:`TrainingRun.command`: training data, initialisation,
training, the steps after it, held-out figures, provenance and export, in that order.
A plugin's ``Run`` fills in what is its own (:meth:`~TrainingRun.training_data`,
:meth:`~TrainingRun.initial`, :meth:`~TrainingRun.network`, :meth:`~TrainingRun.payload`,
and where it has them :meth:`~TrainingRun.after_training` and
:meth:`~TrainingRun.heldout_figures`); :meth:`~TrainingRun.cached` renders its views of
each home once (:mod:`ssga_bench.training_data`). :func:`training_main` is the command
line every training module has.
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import json
import math
import platform
import shlex
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from ssga_core.errors import InputError, SsgaError

if TYPE_CHECKING:
    import torch


def training_log(message: str) -> None:
    """One timestamped progress line of a training command."""
    print(f"[{datetime.datetime.now().strftime('%H:%M:%S')}] {message}", flush=True)


def config_json(config: Any) -> dict[str, Any]:
    """A training config (a dataclass) as JSON: tuples become lists, as they read back from a file."""
    import dataclasses
    import json

    return json.loads(json.dumps(dataclasses.asdict(config)))


def cosine_lr(peak: float, step: int, steps: int, floor: float = 0.1) -> float:
    """Cosine decay from ``peak`` at step 0 to ``floor * peak`` at the last step."""
    return peak * (floor + (1 - floor) * 0.5 * (1 + math.cos(math.pi * step / steps)))


def poly_lr(peak: float, step: int, steps: int, power: float = 0.9) -> float:
    """The "poly" decay ``peak * (1 - step / steps) ** power`` (CSAIL's and DeepLab's)."""
    return peak * (1 - step / steps) ** power


def photometric_jitter(images: np.ndarray, rng: np.random.Generator, jitter: float) -> np.ndarray:
    """``(N, H, W, 3)`` images in [0, 1] under random photometric jitter, clipped to [0, 1]: per image a
    gain within ``1 +- jitter`` times a per-channel gain within ``1 +- jitter / 3``, and an offset
    within ``+- jitter / 2`` (drawn from ``rng`` in that order)."""
    n = len(images)
    gain = rng.uniform(1 - jitter, 1 + jitter, (n, 1, 1, 1)) * rng.uniform(1 - jitter / 3, 1 + jitter / 3, (n, 1, 1, 3))
    return np.clip(images * gain + rng.uniform(-jitter / 2, jitter / 2, (n, 1, 1, 1)), 0.0, 1.0)


class TrainingRun:
    """A training command's folder ``out``: its config (a rerun with another one is refused,
    so a resumed run never mixes two), the seconds spent per phase (kept across resumes),
    and the staged, resumable optimisation loop :meth:`train`.
    """

    metrics: ClassVar[tuple[str, ...]] = ("loss",)
    """Names of the figures :meth:`train_step` returns, in order (the first is the loss)."""
    rng_stream: ClassVar[int] = 2
    """Step ``s`` of stage ``k`` draws its batch from ``default_rng([seed, rng_stream, k, s])``: the
    same batches however often the run is interrupted (each plugin keeps the stream its packaged
    weights were trained with)."""
    unit: ClassVar[str] = "images"
    """What a batch counts, for the progress line's rate."""

    def __init__(self, config: Any, out: Path) -> None:
        from ssga_bench.io import read_json, write_json

        self.config, self.out = config, out
        out.mkdir(parents=True, exist_ok=True)
        stored = out / "config.json"
        if stored.is_file():
            if read_json(stored) != config_json(config):
                raise InputError(f"{out}: holds a run of another config ({stored}); use a new --out or delete it")
        else:
            write_json(stored, config_json(config))
        times = out / "times.json"
        self.times: dict[str, float] = read_json(times) if times.is_file() else {}

    def timed(self, phase: str, seconds: float) -> None:
        from ssga_bench.io import write_json

        self.times[phase] = self.times.get(phase, 0.0) + seconds
        write_json(self.out / "times.json", self.times)

    # ------------------------------------------------------------------ hooks

    def begin_stage(self, stage: int, data: Any) -> Any:
        """What :meth:`train_step` gets as ``data`` in ``stage`` (called once per stage that has steps left)."""
        return data

    def learning_rate(self, stage: int, step: int, steps: int) -> float:
        return self.config.lr[stage]

    def batch_size(self, stage: int) -> int:
        """Samples per step (the progress line's rate); ``stages[stage][2]`` unless overridden."""
        return int(self.config.stages[stage][2])

    def train_step(self, net: torch.nn.Module, optimizer: torch.optim.Optimizer, stage: int, data: Any, rng: np.random.Generator) -> Sequence[float]:
        """One optimiser step on a batch drawn with ``rng``; returns the :attr:`metrics`."""
        raise NotImplementedError

    # ------------------------------------------------------------------ the command's own parts

    module: ClassVar[str] = ""
    """``python -m MODULE`` runs this training (recorded in the provenance)."""
    what: ClassVar[str] = ""
    """What the exported weights are, in words (the provenance's ``what``)."""
    export_name: ClassVar[str] = ""
    """The default :meth:`export` writes ``NAME.pt`` and ``NAME.json``."""

    def training_data(self) -> Any:
        """The training views (rendered once per home: :meth:`cached`); ``len()`` counts them."""
        raise NotImplementedError

    def initial(self, data: Any) -> torch.nn.Module:
        """The seeded initialisation: training starts from it and the held-out figures compare against it."""
        raise NotImplementedError

    def network(self) -> torch.nn.Module:
        """A new network of the layout trained; the initialisation is loaded into it before training."""
        raise NotImplementedError

    def optimizer(self, net: torch.nn.Module) -> torch.optim.Optimizer:
        import torch

        return torch.optim.Adam(net.parameters(), lr=self.config.lr[0])

    def training_input(self, data: Any) -> Any:
        """What :meth:`train` hands :meth:`begin_stage`: the views, and whatever the steps need besides."""
        return data

    def after_training(self, net: torch.nn.Module, data: Any) -> dict[str, Any]:
        """Steps after the optimisation (a whitening, a calibration); returns the figures they add."""
        return {}

    def heldout_figures(self, init: torch.nn.Module, net: torch.nn.Module) -> dict[str, Any]:
        """Figures of the initialisation and the result on held-out homes (``{"init": ..., "trained": ...}``)."""
        return {}

    def provenance_extra(self, net: torch.nn.Module) -> dict[str, Any]:
        """The plugin's own provenance fields (training and held-out seeds, home settings, the network's options)."""
        return {}

    def describe(self, net: torch.nn.Module) -> str:
        return self.what

    def payload(self, net: torch.nn.Module) -> dict[str, Any]:
        """What the exported file holds besides the provenance."""
        return {"state_dict": net.state_dict()}

    def export(self, net: torch.nn.Module, provenance: dict[str, Any], folder: Path) -> Path:
        """Write the weights into ``folder``; returns what was written (the file, or a folder of files)."""
        return export_checkpoint(folder, self.export_name, self.payload(net), provenance)

    def cached(self, phase: str, views: Callable[[Path], Any]) -> Any:
        """``views(folder)``, timed as ``phase``: a plugin's views of its homes, each home rendered
        once into the run folder's ``views/`` (:func:`~ssga_bench.cached_homes`)."""
        t = time.perf_counter()
        data = views(self.out / "views")
        self.timed(phase, time.perf_counter() - t)
        return data

    # ------------------------------------------------------------------ the command

    @classmethod
    def run_training(cls, config: Any, out: Path, export_to: Path, *, evaluate_heldout: bool = True, argv: Sequence[str] | None = None) -> Path:
        """:meth:`command` of a run in ``out``: what :func:`training_main` calls."""
        return cls(config, out).command(export_to, evaluate_heldout=evaluate_heldout, argv=argv)

    def command(self, export_to: Path, *, evaluate_heldout: bool = True, argv: Sequence[str] | None = None) -> Path:
        """The whole training command: data, initialisation, training, the steps after it,
        held-out figures, provenance and export; returns what :meth:`export` wrote."""
        started = datetime.datetime.now(datetime.timezone.utc)
        self.invocation = command_line(self.module, argv)  # as typed: a record written on the way (a calibration) names it
        data = self.training_data()
        homes = getattr(self.config, "train_seeds", None)  # the config's own field, where it has one
        training_log(f"{len(data)} training {self.unit}" + (f" of {len(homes)} homes" if homes else ""))
        init = self.initial(data)
        net = self.network()
        net.load_state_dict(init.state_dict())
        net, history = self.train(net, self.optimizer(net), self.training_input(data))
        figures = self.figures(history)
        figures.update(self.after_training(net, data))
        if evaluate_heldout:
            t = time.perf_counter()
            init.eval()
            heldout = self.heldout_figures(init, net)
            if heldout:  # a plugin without held-out figures records none
                figures["heldout"], figures["heldout_seconds"] = heldout, round(time.perf_counter() - t, 1)
                training_log(f"held-out figures: {json.dumps(heldout)}")
        provenance = training_provenance(self.describe(net), self.module, argv, started, self.config, figures, **self.provenance_extra(net))
        written = self.export(net, provenance, export_to)
        size = sum(f.stat().st_size for f in written.iterdir() if f.suffix in {".pt", ".pth"}) if written.is_dir() else written.stat().st_size
        training_log(f"exported {written} ({size / 1e6:.1f} MB); training took {figures['training_seconds'] / 60:.1f} min")
        return written

    # ------------------------------------------------------------------ the loop

    def train(self, net: torch.nn.Module, optimizer: torch.optim.Optimizer, data: Any) -> tuple[torch.nn.Module, list[list[float]]]:
        """Every stage's steps from the last checkpoint in ``out`` on; returns the network (in eval
        mode) and the history: one ``[stage, step, *metrics]`` row per step of the whole run."""
        from ssga_bench.learned import load_checkpoint

        c = self.config
        stage, step, history = 0, 0, []
        state_path = self.out / "state.pt"
        if state_path.is_file():
            state = load_checkpoint(state_path, "training state")
            net.load_state_dict(state["state_dict"])
            optimizer.load_state_dict(state["optimizer"])
            stage, step, history = int(state["stage"]), int(state["step"]), [list(h) for h in state["history"]]
            training_log(f"resuming at stage {stage + 1}, step {step}")
        while stage < len(c.stages):
            size, steps = c.stages[stage][:2]
            stage_data = self.begin_stage(stage, data) if step < steps else None
            t0, window = time.perf_counter(), []
            net.train()
            while step < steps:
                lr = self.learning_rate(stage, step, steps)
                for group in optimizer.param_groups:
                    group["lr"] = lr
                values = [float(v) for v in self.train_step(net, optimizer, stage, stage_data, np.random.default_rng([c.seed, self.rng_stream, stage, step]))]
                step += 1
                window.append(values)
                history.append([stage, step, *values])
                if step % c.checkpoint_every == 0 or step == steps:
                    elapsed = time.perf_counter() - t0
                    self.timed(f"stage{stage + 1}", elapsed)
                    t0 = time.perf_counter()
                    self._save_state(net, optimizer, stage, step, history)
                    rate = len(window) * self.batch_size(stage) / elapsed
                    eta = (steps - step) * self.batch_size(stage) / rate
                    means = ", ".join(f"{name} {value:.4g}" for name, value in zip(self.metrics, np.mean(window, axis=0), strict=True))
                    training_log(
                        f"stage {stage + 1}/{len(c.stages)} ({size} px) step {step}/{steps}: {means}, lr {lr:.2g}, "
                        f"{rate:.1f} {self.unit}/s, stage ends in {eta / 60:.1f} min"
                    )
                    window = []
            stage, step = stage + 1, 0
            self._save_state(net, optimizer, stage, step, history)
        net.eval()
        return net, history

    def _save_state(self, net: torch.nn.Module, optimizer: torch.optim.Optimizer, stage: int, step: int, history: list[list[float]]) -> None:
        from ssga_bench.io import atomic_write_bytes
        from ssga_bench.learned import checkpoint_bytes

        state = {"state_dict": net.state_dict(), "optimizer": optimizer.state_dict(), "stage": stage, "step": step, "history": history}
        atomic_write_bytes(self.out / "state.pt", checkpoint_bytes(state))

    # ------------------------------------------------------------------ figures

    def figures(self, history: list[list[float]]) -> dict[str, Any]:
        """Time spent (per phase) and, per stage, the mean of each metric over its first and last steps."""
        loss = []
        for stage, (size, steps, *rest) in enumerate(self.config.stages):
            rows = np.array([h[2:] for h in history if int(h[0]) == stage], dtype=np.float64).reshape(-1, len(self.metrics))
            if len(rows):
                w = max(1, min(50, len(rows) // 4))
                first, last = rows[:w].mean(axis=0), rows[-w:].mean(axis=0)
                loss.append({
                    "size": size, "steps": steps, **({"batch": rest[0]} if rest else {}), "window": w,
                    "first": {name: round(float(v), 5) for name, v in zip(self.metrics, first, strict=True)},
                    "last": {name: round(float(v), 5) for name, v in zip(self.metrics, last, strict=True)},
                })
        return {"training_seconds": round(sum(self.times.values()), 1), "seconds": {k: round(v, 1) for k, v in self.times.items()}, "loss": loss}


def training_provenance(what: str, module: str, argv: Sequence[str] | None, started: datetime.datetime, config: Any, figures: dict[str, Any], **extra: Any) -> dict[str, Any]:
    """The record exported weights carry: what they are, the command that made them, when, from
    which config, with which figures, on which torch and Python (``extra``: the plugin's own)."""
    import torch

    return {
        "what": what,
        "command": command_line(module, argv),
        "date": started.isoformat(timespec="seconds"),
        **extra,
        "config": config_json(config),
        "figures": figures,
        "torch": str(torch.__version__),
        "python": platform.python_version(),
        "threads": torch.get_num_threads(),
    }


def command_line(module: str, argv: Sequence[str] | None) -> str:
    """``python -m MODULE ARGS`` as the user typed it (``argv`` None: this process's own arguments)."""
    return f"python -m {module} " + shlex.join(sys.argv[1:] if argv is None else list(argv))


def export_checkpoint(folder: Path, name: str, payload: dict[str, Any], provenance: dict[str, Any]) -> Path:
    """``folder/NAME.pt`` (``payload`` plus the provenance) and ``folder/NAME.json`` (the provenance, the file's size and SHA-256)."""
    from ssga_bench.io import atomic_write_bytes, write_json
    from ssga_bench.learned import checkpoint_bytes

    path = folder / f"{name}.pt"
    data = checkpoint_bytes({**payload, "provenance": provenance})
    atomic_write_bytes(path, data)
    write_json(folder / f"{name}.json", {**provenance, "file": path.name, "bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()})
    return path


def training_main(
    module: str,
    doc: str,
    run_training: Callable[..., Path],
    config: Any,
    argv: Sequence[str] | None,
    *,
    exports: str,
    default_export: Callable[[Path], Path] = lambda out: out,
) -> int:
    """The command line every training module has: ``--out``, ``--export``, ``--threads``, ``--no-eval``.

    Calls ``run_training(config, out, export, evaluate_heldout=..., argv=argv)``; an
    ssga error is one ``error:`` line and exit status 1.
    """
    import torch

    parser = argparse.ArgumentParser(prog=f"python -m {module}", description=doc.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True, help="run folder: caches, checkpoints (resumable), results")
    parser.add_argument("--export", type=Path, default=None, help=f"folder for {exports} (default: {default_export(Path('--out')).as_posix()})")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--no-eval", action="store_true", help="skip the held-out figures")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    try:
        run_training(config, args.out, args.export or default_export(args.out), evaluate_heldout=not args.no_eval, argv=argv)
    except SsgaError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


def evaluation_main(
    module: str,
    doc: str,
    argv: Sequence[str] | None,
    *,
    held_out: Callable[[argparse.Namespace], Any],
    measure: Callable[[str | None, Any, argparse.Namespace], dict[str, Any]],
    add_arguments: Callable[[argparse.ArgumentParser], None] | None = None,
) -> int:
    """The command line every plugin's ``evaluate`` module has: held-out figures of one or
    more weights files, as JSON.

    ``--weights`` (repeatable; default: the packaged weights, passed to ``measure`` as
    None), ``--threads``, ``--json FILE``, and the plugin's own ``add_arguments``. The
    held-out views (``held_out(args)``) are made once and every weights file is scored on
    them (``measure(weights, views, args)``); an ssga error is one ``error:`` line and exit 1.
    """
    import torch

    from ssga_bench.io import write_json

    parser = argparse.ArgumentParser(prog=f"python -m {module}", description=doc.split("\n\n")[0])
    parser.add_argument("--weights", action="append", default=None, help="weights to score (default: the packaged ones); repeatable")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures to this file")
    if add_arguments:
        add_arguments(parser)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    results: dict[str, Any] = {}
    try:
        t = time.perf_counter()
        views = held_out(args)
        # Progress on stderr: the figures on stdout stay pure JSON, for a pipe.
        print(f"{len(views)} held-out views ready ({time.perf_counter() - t:.0f} s)", file=sys.stderr, flush=True)
        for weights in args.weights or [None]:
            t = time.perf_counter()
            results[weights or "packaged"] = measure(weights, views, args)
            print(f"{weights or 'packaged weights'}: scored in {time.perf_counter() - t:.0f} s", file=sys.stderr, flush=True)
        print(json.dumps(results, indent=2))
        if args.json:
            write_json(args.json, results)
    except SsgaError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0
