"""Experiment configs: one TOML file, validated in two steps, every problem reported at once.

Step 1 checks the file's shape against :class:`ExperimentConfig`. Step 2 resolves each
``{ name = ... }`` stage reference in the plugin registry, validates its parameters
with that plugin's own ``Config``, parses each variant string and checks each bound
variant against its plugins and the workspace's views. Problems come back as
``path: message`` lines, e.g. ``variants[2].descriptor.k: Input should be greater
than 0``.

A minimal config::

    [workspace]
    name = "procedural"

    [stages]                              # bound to every variant unless it overrides
    parser = { name = "slico" }
    descriptor = { name = "dense-sift" }  # swap the descriptor of all variants here
    synthesizer = { name = "depth-warp" }

    variants = ["PDS", "PSD", "SPD", "DSP", "PD", "DS", "SD", "D"]  # (top level)

or, to bind one variant differently::

    [[variants]]
    variant = "SPD2"
    parser = { name = "slico", n_segments = 50 }
"""

from __future__ import annotations

import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError

from ssga_core.errors import ConfigError, SsgaError
from ssga_core.pipeline import BoundVariant, table_label
from ssga_core.plugins import Registry, default_registry
from ssga_core.protocol import ProtocolConfig
from ssga_core.stages import Stage, StageConfig
from ssga_core.variants import Variant, check_binding, parse_variant

STAGE_FIELDS = ("parser", "descriptor", "synthesizer")


class StageRef(BaseModel):
    """A stage picked by name, with its parameters beside the name.

    ``preset`` (optional) starts from one of the plugin's named presets; parameters
    given beside it override the preset's.
    """

    model_config = ConfigDict(extra="allow", frozen=True)

    name: str = Field(description="The registered name of the implementation.")
    preset: str | None = Field(default=None, description="One of the plugin's presets to start from.")

    @property
    def params(self) -> dict[str, Any]:
        """The parameters beside ``name`` and ``preset``."""
        return dict(self.model_extra or {})

    @property
    def options(self) -> dict[str, Any]:
        """Everything but ``name``: the parameters, and ``preset`` if one is named."""
        return {**self.params, **({"preset": self.preset} if self.preset else {})}


# One subclass per kind, so the JSON schema can list each kind's installed plugins.
class ParserRef(StageRef):
    """A scene parser (stage P)."""


class DescriptorRef(StageRef):
    """A scene descriptor (stage D)."""


class SynthesizerRef(StageRef):
    """A view synthesizer (stage S)."""


class FuserRef(StageRef):
    """A late-fusion rule."""


class WorkspaceRef(StageRef):
    """A workspace source."""


REF_TYPES: dict[str, type[StageRef]] = {
    "parser": ParserRef,
    "descriptor": DescriptorRef,
    "synthesizer": SynthesizerRef,
    "fuser": FuserRef,
    "workspace": WorkspaceRef,
}


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class StageDefaults(_Strict):
    """Stages bound to every variant that does not name its own."""

    parser: ParserRef | None = None
    descriptor: DescriptorRef | None = None
    synthesizer: SynthesizerRef | None = None


def _variant_entry(value: Any) -> Any:
    return {"variant": value} if isinstance(value, str) else value


class VariantSpec(_Strict):
    """One variant: its order (with optional preset number) and any stages it binds itself."""

    variant: str = Field(description="Order and optional preset number, e.g. 'PDS' or 'SPD2'.")
    label: str | None = Field(default=None, description="Row name in reports; default: the paper's notation, e.g. 'P-SL (SPD1)'.")
    parser: ParserRef | None = None
    descriptor: DescriptorRef | None = None
    synthesizer: SynthesizerRef | None = None


class TrainingConfig(_Strict):
    """The per-variant GCN place classifier and its training data."""

    hidden: int = Field(default=256, gt=0, description="Hidden width of the GCN.")
    layers: int = Field(default=2, ge=1, description="Graph-convolution layers.")
    dropout: float = Field(default=0.5, ge=0.0, lt=1.0)
    readout: Literal["mean", "weighted"] = Field(
        default="mean", description="Pool node states by their mean, or by their node weights (whole image 1, parts 1/K)."
    )
    epochs: int = Field(default=200, gt=0)
    lr: float = Field(default=1e-3, gt=0.0)
    weight_decay: float = Field(default=5e-4, ge=0.0)
    patience: int = Field(default=20, gt=0, description="Epochs without validation improvement before stopping.")
    validation_fraction: float = Field(default=0.2, gt=0.0, lt=1.0, description="Share of training graphs held out for early stopping.")
    synthetic_per_class: int = Field(default=4, gt=0, description="Synthetic graphs per class (variants with S): the target and jittered copies.")
    jitter_m: float = Field(default=0.15, ge=0.0, description="Jittered copies move up to this far from the training viewpoint, metres.")
    jitter_deg: float = Field(default=5.0, ge=0.0, description="...and turn up to this much, degrees.")
    real_for_every_class: bool = Field(
        default=True,
        description="Variants without S train each class of a cell on the cell's real graph (the paper: they 'simply use "
        "available training images as they are'); false trains them on the real classes only.",
    )
    seed: int = 0


class ExperimentConfig(_Strict):
    """A whole experiment: where views come from, the variants and their stages, training, fusion."""

    workspace: WorkspaceRef
    stages: StageDefaults = StageDefaults()
    variants: list[Annotated[VariantSpec, BeforeValidator(_variant_entry)]] = Field(min_length=1)
    protocol: ProtocolConfig = ProtocolConfig()
    training: TrainingConfig = TrainingConfig()
    fuser: FuserRef = FuserRef(name="rrf")
    output: Path = Field(default=Path("runs/experiment"), description="Folder for caches, checkpoints and reports.")


@dataclass(frozen=True)
class ResolvedStage:
    """A stage reference resolved to its class and validated config."""

    kind: str
    cls: type[Stage]
    config: StageConfig

    def create(self) -> Stage:
        return self.cls(self.config)


@dataclass(frozen=True)
class ResolvedVariant:
    variant: Variant
    label: str
    stages: Mapping[str, ResolvedStage]
    """The stages its order uses, by kind."""

    def bind(self) -> BoundVariant:
        """The variant with fresh stage instances, ready to build graphs."""
        made = {kind: stage.create() for kind, stage in self.stages.items()}
        return BoundVariant(self.variant, label=self.label, **made)


@dataclass(frozen=True)
class Experiment:
    """A validated config with every stage resolved."""

    config: ExperimentConfig
    workspace: ResolvedStage
    variants: list[ResolvedVariant]
    fuser: ResolvedStage
    source: str = "<config>"


def format_loc(loc: Iterable[str | int]) -> str:
    """``('variants', 2, 'descriptor', 'k')`` -> ``variants[2].descriptor.k``."""
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(top level)"


def _pydantic_problems(exc: ValidationError, prefix: tuple[str | int, ...] = ()) -> list[str]:
    problems = []
    for err in exc.errors(include_url=False):
        loc = [p for p in err["loc"] if not (isinstance(p, str) and p.startswith("function-"))]
        msg = err["msg"]
        if err["type"] == "extra_forbidden":
            msg = "unknown key (misspelled?)"
        problems.append(f"{format_loc((*prefix, *loc))}: {msg}")
    return problems


def load_experiment(path: str | Path, registry: Registry | None = None) -> Experiment:
    """Read and validate an experiment config file; raise :class:`ConfigError` with every problem."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SsgaError(f"{path}: no such config file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SsgaError(f"{path}: cannot read the config: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise SsgaError(f"{path}: not valid TOML: {exc}") from None
    return validate_experiment(data, registry, source=str(path), base_dir=path.parent)


def validate_experiment(
    data: Mapping[str, Any], registry: Registry | None = None, *, source: str = "<config>", base_dir: Path | None = None
) -> Experiment:
    """Validate a config mapping (see the module docstring).

    Args:
        base_dir: relative paths in stage parameters (fields typed ``Path``, such as a
            mesh file) are taken relative to this folder, the config file's.
    """
    try:
        config = ExperimentConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(source, _pydantic_problems(exc)) from None
    registry = registry or default_registry()
    problems: list[str] = []
    resolve = _Resolver(registry, problems, base_dir)

    workspace = resolve(config.workspace, "workspace", ("workspace",))
    fuser = resolve(config.fuser, "fuser", ("fuser",))
    defaults = {f: resolve(getattr(config.stages, f), f, ("stages", f)) for f in STAGE_FIELDS}
    available = workspace.cls.produces if workspace else None

    variants: list[ResolvedVariant] = []
    labels: dict[str, int] = {}
    for i, spec in enumerate(config.variants):
        at = ("variants", i)
        try:
            variant = parse_variant(spec.variant)
        except SsgaError as exc:
            problems.append(f"{format_loc((*at, 'variant'))}: {exc}")
            continue
        stages: dict[str, ResolvedStage] = {}
        classes: dict[str, type[Stage]] = {}
        for kind in variant.kinds():
            ref = getattr(spec, kind)
            if ref is None:
                ref = getattr(config.stages, kind)
                stage = defaults[kind]
                if ref is None:
                    problems.append(f"{format_loc((*at, kind))}: {variant} needs a {kind}; bind one here or in [stages]")
            else:
                stage = resolve(ref, kind, (*at, kind))
            if stage is not None:
                stages[kind] = stage
            if ref is not None and id(ref) in resolve.classes:
                classes[kind] = resolve.classes[id(ref)]
        # Check the binding whenever every class is known, even if some parameters were
        # wrong, so one run reports both kinds of problem.
        if available is not None and len(classes) == len(variant.order):
            problems.extend(f"{format_loc(at)}: {p}" for p in check_binding(variant, classes, available))
        if len(stages) < len(variant.order):
            continue
        parser = stages["parser"].cls if "parser" in stages else None
        label = spec.label or table_label(variant, parser, stages["descriptor"].cls)
        if label in labels:
            problems.append(f"{format_loc((*at, 'variant'))}: label {label!r} is also variants[{labels[label]}]'s; give one a preset number (e.g. {variant.order}2) or a label")
        labels.setdefault(label, i)
        variants.append(ResolvedVariant(variant, label, stages))

    if problems or workspace is None or fuser is None:
        raise ConfigError(source, problems)
    return Experiment(config=config, workspace=workspace, variants=variants, fuser=fuser, source=source)


class _Resolver:
    """Resolves stage references to classes and validated configs, collecting problems."""

    def __init__(self, registry: Registry, problems: list[str], base_dir: Path | None = None) -> None:
        self.registry = registry
        self.problems = problems
        self.base_dir = base_dir
        self.classes: dict[int, type[Stage]] = {}
        """Class of each reference whose name resolved, by ``id(ref)``."""

    def __call__(self, ref: StageRef | None, kind: str, at: tuple[str | int, ...]) -> ResolvedStage | None:
        if ref is None:
            return None
        try:
            cls = self.registry.get(kind, ref.name)
        except SsgaError as exc:
            self.problems.append(f"{format_loc((*at, 'name'))}: {exc}")
            return None
        self.classes[id(ref)] = cls
        params: dict[str, Any] = {}
        if ref.preset is not None:
            if ref.preset not in cls.presets:
                known = ", ".join(sorted(cls.presets)) or "none"
                self.problems.append(f"{format_loc((*at, 'preset'))}: {kind} {ref.name!r} has no preset {ref.preset!r}; its presets: {known}")
                return None
            params.update(cls.presets[ref.preset])
        params.update(ref.params)
        try:
            config = cls.Config.model_validate(params)
        except ValidationError as exc:
            self.problems.extend(_pydantic_problems(exc, at))
            return None
        if self.base_dir is not None:
            relative = {k: self.base_dir / v for k, v in config if isinstance(v, Path) and not v.is_absolute()}
            config = config.model_copy(update=relative) if relative else config
        return ResolvedStage(kind, cls, config)


def resolve_stage(kind: str, ref: Mapping[str, Any], registry: Registry | None = None, *, source: str = "<options>") -> ResolvedStage:
    """Resolve one ``{name = ..., ...}`` stage reference outside an experiment config (CLI options)."""
    problems: list[str] = []
    try:
        parsed = REF_TYPES[kind].model_validate(ref)
    except ValidationError as exc:
        raise ConfigError(source, _pydantic_problems(exc, (kind,))) from None
    stage = _Resolver(registry or default_registry(), problems)(parsed, kind, (kind,))
    if stage is None:
        raise ConfigError(source, problems)
    return stage


def experiment_schema(registry: Registry | None = None) -> dict[str, Any]:
    """JSON schema of the config file, with each stage reference listing the installed plugins' own schemas."""
    registry = registry or default_registry()
    schema = ExperimentConfig.model_json_schema()
    defs = schema.setdefault("$defs", {})
    for kind, ref_type in REF_TYPES.items():
        choices = []
        for entry in (e for e in registry if e.kind == kind):
            sub = entry.cls.Config.model_json_schema(ref_template="#/$defs/{model}")
            defs.update(sub.pop("$defs", {}))
            props = {"name": {"const": entry.name}, **sub.get("properties", {})}
            if entry.cls.presets:
                props["preset"] = {"enum": sorted(entry.cls.presets)}
            choices.append({**sub, "title": f"{kind} {entry.name}", "properties": props, "required": ["name", *sub.get("required", [])]})
        if choices:
            defs[ref_type.__name__] = {"description": ref_type.__doc__, "oneOf": choices}
    return schema

