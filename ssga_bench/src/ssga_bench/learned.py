"""What every learned (torch) stage shares: the ``weights`` and ``device`` fields, strict
checkpoint loading with one-line errors, and the "random weights" caveat.

A learned plugin's config subclasses :class:`LearnedConfig` (beside its other bases) and
its stage class mixes in :class:`Learned`::

    class PnvConfig(BoWDescriptorConfig, LearnedConfig):
        weights: str = Field(default="pnv-light.pt", description=WEIGHTS_HELP)

    class Pnv(Learned, BoWDescriptor):
        def _network(self):
            state = load_checkpoint(self.weights_file(HERE / "weights"), self)
            load_strict(net, state["state_dict"], self, path)

Conventions (the same in every learned plugin):

* ``weights`` names the checkpoint: a path (relative paths are looked up in the plugin's
  own ``weights/`` folder first, then the working directory), or ``"random"``: random
  initialisation, **for tests only**. A stage on random weights returns the caveat
  ``"random weights"``, which the core appends to every label it takes part in.
* Checkpoints load with ``torch.load(..., weights_only=True)`` and strict
  ``load_state_dict``: a missing file, a file torch cannot read, and a state dict whose
  keys or shapes differ from the network's each raise a one-line
  :class:`~ssga_core.errors.CheckpointError` naming the config field, the file and what
  was expected.
* ``device``: ``"auto"`` (CUDA when present), ``"cpu"`` or ``"cuda"``.
"""

from __future__ import annotations

import io
import threading
import warnings
from collections.abc import Callable, Hashable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Literal, TypeVar

from pydantic import Field

from ssga_core.errors import CheckpointError, InputError, MissingWeightsError
from ssga_core.stages import StageConfig
from ssga_bench.io import is_file

if TYPE_CHECKING:  # torch loads when a network is built, not when a plugin registers (`ssga --help` stays fast)
    import torch

T = TypeVar("T")

RANDOM_WEIGHTS = "random"
"""The ``weights`` value for random initialisation (tests only; every output says so)."""

RANDOM_SEED = 0
"""Random weights are drawn from this seed: the same network in every process (worker processes agree)."""

Device = Literal["auto", "cpu", "cuda"]


class LearnedConfig(StageConfig):
    """The fields of every learned stage; subclasses give ``weights`` its default and help."""

    weights: str = Field(
        default=RANDOM_WEIGHTS,
        min_length=1,
        description="Checkpoint file (relative: the plugin's weights/ folder, then the working directory), or 'random' (tests only).",
    )
    device: Device = Field(default="auto", description="Where the network runs: 'auto' (CUDA when present), 'cpu' or 'cuda'.")


def weights_field(default: str, holds: str, *, what: str = "Checkpoint") -> Any:
    """The ``weights`` field of a plugin that ships the light network ``default``, trained here;
    ``holds`` names what else a user may give it (an official release)."""
    return Field(
        default=default,
        min_length=1,
        description=f"{what} (relative: the plugin's weights/ folder, then the working directory): the light network "
        f"trained here (default), {holds}, or 'random' (tests only).",
    )


def network_field(layouts: str, *, files: str = "the weights file's") -> Any:
    """The ``network`` field of a plugin whose files name their own network (:func:`read_layout`):
    ``layouts`` says what each choice is; left out, the file decides."""
    return Field(
        default=None,
        description=f"{layouts} Left out: {files}, read from its keys and shapes ('light' for random weights); set, the file must hold it.",
    )


class Learned:
    """Mixin for a stage whose config is a :class:`LearnedConfig`."""

    config: Any
    name: str
    kind: str

    layouts: ClassVar[tuple[Layout, ...]] = ()
    """The networks a ``weights`` file can hold (official releases, the light ones trained here):
    the file's keys and shapes say which (:func:`read_layout`); ``ssga plugins`` lists them."""

    reloaded: ClassVar[tuple[str, ...]] = ()
    """The attributes ``self._load()`` returns, in order (the network, and what comes with it):
    they load when the stage is made (a bad ``weights`` file is reported before any work); a
    stage pickled for a worker process leaves them out, and the worker loads its own copy,
    from the file or from the same seed, instead of receiving a network through a pipe."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._set_reloaded()

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        for name in self.reloaded:
            state.pop(name, None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._set_reloaded()

    def _set_reloaded(self) -> None:
        """Set the :attr:`reloaded` attributes from ``self._load()`` (nothing, for a stage without them)."""
        if self.reloaded:
            loaded = self._load()  # type: ignore[attr-defined]
            for name, value in zip(self.reloaded, loaded if len(self.reloaded) > 1 else (loaded,), strict=True):
                setattr(self, name, value)

    packaged_weights: ClassVar[Path | None] = None
    """The plugin's own ``weights/`` folder, if it ships weights trained here (their provenance is beside them)."""
    trained_on: ClassVar[str] = ""
    """The workspace source whose homes the packaged weights were trained on (its name)."""

    @classmethod
    def caveat(cls, config: Any) -> str:
        return "random weights" if getattr(config, "weights", None) == RANDOM_WEIGHTS else ""

    def once_per_process(self, key: tuple[Any, ...], load: Callable[[], T]) -> T:
        """``load()``'s result for ``key``, made once per process and shared by every instance and
        thread of this stage with the same key: a network is read from its file once, however many
        variants use it. ``key`` holds what the result depends on: the files' :func:`file_stamp`
        (or ``RANDOM_WEIGHTS``), the config fields that build it, the device."""
        key = (self.kind, self.name, *key)
        with _LOADED_LOCK:
            if key not in _LOADED:
                _LOADED[key] = load()
            return _LOADED[key]  # type: ignore[no-any-return]

    @classmethod
    def out_of_domain(cls, config: Any, workspace: str) -> str:
        """What a report says when ``config`` runs the packaged weights, trained on
        :attr:`trained_on` homes, on the views of another workspace source; else ``""``."""
        if cls.packaged_weights is None or not cls.trained_on or workspace == cls.trained_on or config.weights == RANDOM_WEIGHTS:
            return ""
        path = Path(config.weights).expanduser()
        packaged = cls.packaged_weights / path.name
        found_there = path.parent.resolve() == cls.packaged_weights.resolve() if path.is_absolute() else packaged.exists()
        if not found_there:
            return ""
        return f"{cls.kind} {cls.name!r} runs the weights trained here on {cls.trained_on} homes ({path.name}), not on views like this {workspace!r} workspace's"

    @property
    def who(self) -> str:
        """The stage as its errors name it: ``parser 'detic'``."""
        return f"{self.kind} {self.name!r}"

    @property
    def random_weights(self) -> bool:
        return self.config.weights == RANDOM_WEIGHTS

    @property
    def device(self) -> torch.device:
        return resolve_device(self.config.device, self.who)

    def weights_file(self) -> Path:
        """The checkpoint ``config.weights`` names (it must exist), looked up in :attr:`packaged_weights` first."""
        return find_weights(self.config.weights, self.packaged_weights, self.who)

    def load_network(
        self,
        settings: tuple[Any, ...],
        random: Callable[[], tuple[torch.nn.Module, dict[str, Any]]],
        from_file: Callable[[Path], tuple[torch.nn.Module, dict[str, Any]]],
        *,
        find: Callable[[], Path] | None = None,
        files: Callable[[Path], Sequence[Path]] | None = None,
    ) -> tuple[torch.nn.Module, Path | None]:
        """The network the weights hold, on :attr:`device` in eval mode, and where they are (``None``: random weights).

        ``find()`` (default :meth:`weights_file`) is where ``config.weights`` points;
        ``from_file(path)`` reads it, ``random()`` builds the random-weights network instead.
        Each returns the network and the config fields its weights imply (its ``network``,
        sizes read from the file: :func:`read_layout`'s), which ``self.config`` gets. The
        network is made once per process (:meth:`once_per_process`) for the same weights
        (the :func:`file_stamp` of ``files(path)``, default the path itself), ``settings``
        (the config fields that build it, as given: a field set against the file must
        still fail) and device.
        """
        device = self.device
        path = None if self.random_weights else (find or self.weights_file)().resolve()

        def load() -> tuple[torch.nn.Module, dict[str, Any]]:
            net, fields = random() if path is None else from_file(path)
            return net.to(device).eval(), fields

        stamps = (RANDOM_WEIGHTS,) if path is None else tuple(file_stamp(f) for f in (files(path) if files else (path,)))
        net, fields = self.once_per_process((*stamps, *settings, str(device)), load)
        self.config = self.config.model_copy(update=fields)
        return net, path


_LOADED: dict[tuple[Any, ...], Any] = {}
_LOADED_LOCK = threading.Lock()


def file_stamp(path: Path) -> tuple[str, int, int]:
    """A file's identity for a cache of what was loaded from it: its path, modification time and size."""
    stat = path.stat()
    return str(path), stat.st_mtime_ns, stat.st_size


def resolve_device(choice: str, who: str = "stage") -> torch.device:
    import torch

    if choice == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if choice == "cuda" and not torch.cuda.is_available():
        raise InputError(f"{who}: device = 'cuda', but this torch ({torch.__version__}) sees no CUDA device; use 'auto' or 'cpu'")
    return torch.device(choice)


def find_weights(value: str, packaged: Path | None, who: str, field: str = "weights", expected: str = "a checkpoint file") -> Path:
    """The file ``value`` names: itself if absolute, else under ``packaged`` (when given), then the working directory.

    A missing file is a :class:`MissingWeightsError` naming the config ``field`` and what it should hold.
    """
    if value == RANDOM_WEIGHTS:
        raise ValueError("random weights have no file")
    path = Path(value).expanduser()
    candidates = [path] if path.is_absolute() else [*([packaged / path] if packaged else []), Path.cwd() / path]
    for candidate in candidates:
        if is_file(candidate):  # a path the system cannot look at (too long, through a file) is no file either
            return candidate
    where = " or ".join(str(c) for c in candidates)
    raise MissingWeightsError(f"{who}: config field {field!r} = {value!r}: no such file (looked for {where}); set {field!r} to {expected}")


def load_checkpoint(path: Path, who: str, expected: str = "a torch checkpoint") -> Any:
    """``torch.load(path, weights_only=True)`` on the CPU; any failure is one :class:`CheckpointError` line."""
    import torch

    try:
        with warnings.catch_warnings():  # torch's remarks on a file's pickle protocol: the error below, if any, says what matters
            warnings.simplefilter("ignore")
            return torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise MissingWeightsError(f"{who}: config field 'weights': {path}: no such file; expected {expected}") from None
    except Exception as exc:  # torch raises many kinds (pickle, zip, unpickler) for one cause: not a readable checkpoint
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise CheckpointError(f"{who}: config field 'weights': {path} is not a readable checkpoint ({reason[:160]}); expected {expected}") from None


def load_strict(module: torch.nn.Module, state: Any, who: str, path: Path | str, expected: str = "") -> None:
    """``module.load_state_dict(state, strict=True)``, with mismatches said in one line (first keys of each kind)."""
    what = expected or f"the {type(module).__name__} layout"
    state = tensor_state(state, who, path, what)
    count, problems = state_differences({k: tuple(v.shape) for k, v in module.state_dict().items()}, state)
    if count:
        raise CheckpointError(f"{who}: config field 'weights': {path} does not match {what}: {problems}")
    module.load_state_dict(state, strict=True)


def tensor_state(state: Any, who: str, path: Path | str, expected: str) -> dict[str, torch.Tensor]:
    """``state`` if it is a dict of tensors; else a one-line :class:`CheckpointError`."""
    import torch

    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise CheckpointError(f"{who}: config field 'weights': {path} holds no state dict of tensors; expected {expected}")
    return state


def state_differences(expected: Mapping[str, tuple[int, ...]], state: Mapping[str, Any]) -> tuple[int, str]:
    """How many keys of ``state`` are missing, unexpected or of another shape than ``expected``
    (key -> shape), and the first of each kind in words ("" when they match)."""
    missing = [k for k in expected if k not in state]
    unexpected = [k for k in state if k not in expected]
    shapes = [f"{k} {tuple(state[k].shape)} (expected {tuple(expected[k])})" for k in expected if k in state and tuple(state[k].shape) != tuple(expected[k])]
    problems = []
    for title, keys in (("missing", missing), ("unexpected", unexpected), ("wrong shape", shapes)):
        if keys:
            problems.append(f"{len(keys)} {title}: {', '.join(keys[:3])}{', ...' if len(keys) > 3 else ''}")
    return len(missing) + len(unexpected) + len(shapes), "; ".join(problems)


@dataclass(frozen=True)
class Layout:
    """One network a plugin's checkpoints can hold: an official release or the light network trained here.

    A file names its own layout by its keys and shapes, as the official loaders read
    theirs (Patch-NetVLAD takes its cluster count from ``pool.centroids``): ``weights =
    FILE`` alone is enough, and the config fields the layout implies are set from it.
    """

    name: str
    """As the config names the network (``network = "vgg16"``)."""
    source: str
    """Where such files come from (``ssga plugins``, the plugin's README and errors say it)."""


def read_layout(
    config: Any,
    state: Mapping[str, Any],
    layouts: Sequence[Layout],
    network_of: Callable[[Layout, Mapping[str, Any]], tuple[dict[str, Any], Mapping[str, tuple[int, ...]]]],
    who: str,
    path: Path | str,
) -> tuple[Layout, dict[str, Any]]:
    """The layout whose keys and shapes ``state`` has, and the config fields it implies.

    Args:
        network_of: for a layout and the file's state: the config fields that build that
            network (its ``network``, and any size read from the file, e.g. ``num_pcs``), and
            the network's keys and shapes with those fields.

    Raises:
        CheckpointError: no layout matches (the closest is named, with its first missing,
            unexpected or wrong-shaped keys); or the config sets a field the file contradicts.
    """
    tried = []
    for layout in layouts:
        fields, shapes = network_of(layout, state)
        count, problems = state_differences(shapes, state)
        if count:
            tried.append((count, layout, problems))
            continue
        # Fields the user (or a preset) set, not defaults: those may contradict the file.
        clashes = {k: v for k, v in fields.items() if k in config.model_fields_set and getattr(config, k) is not None and getattr(config, k) != v}
        if clashes:
            said = ", ".join(f"{k} = {getattr(config, k)!r}" for k in clashes)
            held = ", ".join(f"{k} = {v!r}" for k, v in clashes.items())
            raise CheckpointError(
                f"{who}: config field{'s' if len(clashes) > 1 else ''} {said} contradict{'' if len(clashes) > 1 else 's'} config field 'weights': "
                f"{path} holds the {layout.name!r} layout ({layout.source}) with {held}; leave {', '.join(clashes)} out to take the file's"
            )
        return layout, fields
    _, closest, problems = min(tried, key=lambda t: t[0])
    names = ", ".join(repr(layout.name) for layout in layouts)
    raise CheckpointError(f"{who}: config field 'weights': {path} matches none of the layouts it loads ({names}); closest: {closest.name!r}: {problems}")


def seeded(build: Callable[[], T]) -> T:
    """``build()`` with torch's generator seeded with :data:`RANDOM_SEED` (and restored after): random
    weights, the same network in every process."""
    import torch

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(RANDOM_SEED)
        return build()


def meta_shapes(build: Callable[[], torch.nn.Module]) -> dict[str, tuple[int, ...]]:
    """The keys and shapes of the module ``build`` makes, built on torch's meta device (no memory, no init cost)."""
    import torch

    with torch.device("meta"):
        module = build()
    return {k: tuple(v.shape) for k, v in module.state_dict().items()}


CPU_VIEWS_PER_CALL: int | None = 1
"""Views per network call on the CPU (on a GPU each group of one input size is one call).
Batching pays on a GPU, not on a CPU: with one torch thread, as the runner's workers have,
one call of 16 views at 256 x 256 took longer than 16 calls of one (pnv's light network
1.5-1.6x, its VGG16 1.26x, cascade-seg's light network 1.25x; the pnv README's Speed).
Results are the same either way (each plugin's tests/test_batch.py)."""


def network_calls(keys: Sequence[Hashable], device: torch.device) -> list[list[int]]:
    """How a batch of views goes through a network on ``device``: the indices of ``keys`` (each
    view's input size) grouped by key, in the order of their first index, each group one call
    on a GPU and cut into calls of :data:`CPU_VIEWS_PER_CALL` on the CPU."""
    groups: dict[Hashable, list[int]] = {}
    for i, key in enumerate(keys):
        groups.setdefault(key, []).append(i)
    step = (CPU_VIEWS_PER_CALL if device.type == "cpu" else None) or len(keys) or 1
    return [group[start : start + step] for group in groups.values() for start in range(0, len(group), step)]


def checkpoint_bytes(obj: Any) -> bytes:
    """A checkpoint serialised in memory (write it with :func:`ssga_bench.io.atomic_write_bytes`)."""
    import torch

    buffer = io.BytesIO()
    torch.save(obj, buffer)
    return buffer.getvalue()


@contextmanager
def torch_threads(count: int) -> Iterator[None]:
    """Run torch's intra-op work on ``count`` threads (0: leave torch's setting) for the block, restoring it after."""
    import torch

    before = torch.get_num_threads()
    if count:
        torch.set_num_threads(count)
    try:
        yield
    finally:
        torch.set_num_threads(before)
