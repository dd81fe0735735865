"""Stage references and variant bindings in config files: the one path from a config to stage instances.

A stage is picked by name with its parameters beside it (``parser = { name = "slico",
n_segments = 64 }``). :class:`Resolver` turns such a reference into a
:class:`ResolvedStage`: the registered class and its validated config, with relative
paths in the parameters taken from the config file's folder. Every command goes
through it, once; whatever runs afterwards uses the resolved stage and never reads
the raw options again.

The part of a config this module reads is the variants and the stages bound to
them::

    [stages]                              # bound to every variant unless it overrides
    parser = { name = "slico" }
    descriptor = { name = "dense-sift" }  # swap the descriptor of all variants here
    synthesizer = { name = "depth-warp" }

    variants = ["PDS", "PSD", "SPD", "DSP", "PD", "DS", "SD", "D"]  # (top level)

or, to bind one variant differently::

    [[variants]]
    variant = "SPD2"
    parser = { name = "slico", n_segments = 50 }

Everything else in an experiment config (the workspace, protocol, training, fusion)
belongs to the layer that runs experiments, which validates the whole file with the
same helpers. Problems come back all at once, as ``path: message`` lines, e.g.
``variants[2].descriptor.k: Input should be greater than 0``.
"""

from __future__ import annotations

import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, create_model

from ssga_core.data import Data
from ssga_core.errors import ConfigError, InputError, SsgaError
from ssga_core.kinds import KINDS, PIPELINE_KIND_NAMES, kind_named
from ssga_core.pipeline import BoundVariant, table_label
from ssga_core.plugins import Registry
from ssga_core.stages import KeyedConfig, Stage, StageConfig
from ssga_core.variants import Variant, check_binding, parse_variant


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


# One subclass per kind, so the JSON schema can list each kind's installed plugins.
REF_TYPES: dict[str, type[StageRef]] = {
    k.name: type(f"{k.name.title()}Ref", (StageRef,), {"__doc__": f"A {k.name} (implementations {k.verb}), picked by name."}) for k in KINDS
}


class Strict(KeyedConfig):
    """Base of config sections: unknown keys are errors, instances are immutable; a section that keys
    stored runs (``[training]``) names its later settings in ``added_since`` as a stage's config does."""

    model_config = ConfigDict(extra="forbid", frozen=True)


def _stage_fields() -> dict[str, Any]:
    return {name: (REF_TYPES[name] | None, None) for name in PIPELINE_KIND_NAMES}


StageDefaults = create_model(
    "StageDefaults", __base__=Strict, __doc__="Stages bound to every variant that does not name its own.", **_stage_fields()
)


def _variant_entry(value: Any) -> Any:
    return {"variant": value} if isinstance(value, str) else value


VariantSpec = create_model(
    "VariantSpec",
    __base__=Strict,
    __doc__="One variant: its order (with optional preset number) and any stages it binds itself.",
    variant=(str, Field(description="Order and optional preset number, e.g. 'PDS' or 'SPD2'.")),
    label=(
        str | None,
        Field(default=None, description="Row name in reports; default: the paper's notation, e.g. 'P-SL (SPD1)'."),
    ),
    **_stage_fields(),
)


class VariantsConfig(Strict):
    """The variants of a config and the stages bound to them."""

    stages: StageDefaults = StageDefaults()  # type: ignore[valid-type]
    variants: list[Annotated[VariantSpec, BeforeValidator(_variant_entry)]] = Field(min_length=1)  # type: ignore[valid-type]


@dataclass(frozen=True)
class ResolvedStage:
    """A stage reference resolved to its class and validated config."""

    kind: str
    cls: type[Stage]
    config: StageConfig

    @property
    def name(self) -> str:
        return self.cls.name

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


def format_loc(loc: Iterable[str | int]) -> str:
    """``('variants', 2, 'descriptor', 'k')`` -> ``variants[2].descriptor.k``."""
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(top level)"


def pydantic_problems(exc: ValidationError, prefix: tuple[str | int, ...] = ()) -> list[str]:
    """Each error of a pydantic validation as one ``path: message`` line."""
    problems = []
    for err in exc.errors(include_url=False):
        loc = [p for p in err["loc"] if not (isinstance(p, str) and p.startswith("function-"))]
        msg = err["msg"]
        if err["type"] == "extra_forbidden":
            msg = "unknown key (misspelled?)"
        problems.append(f"{format_loc((*prefix, *loc))}: {msg}")
    return problems


def read_toml(path: str | Path) -> dict[str, Any]:
    """A TOML file's contents; a missing, unreadable or malformed file is one line naming it."""
    path = Path(path)
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{path}: no such config file") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a folder, not a config file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the config: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML: {exc}") from None


class Resolver:
    """Resolves stage references to classes and validated configs, collecting problems.

    Args:
        registry: where stage names are looked up.
        base_dir: relative paths in stage parameters (fields typed ``Path``, such as a
            mesh file or a folder of images) are taken from this folder: the config
            file's, or the current directory for options given on the command line.
    """

    def __init__(self, registry: Registry, base_dir: Path | None = None) -> None:
        self.registry = registry
        self.base_dir = base_dir
        self.problems: list[str] = []
        self._classes: dict[int, type[Stage]] = {}

    def stage(self, ref: StageRef | None, kind: str, at: tuple[str | int, ...]) -> ResolvedStage | None:
        """``ref`` resolved, or None (with the problem recorded)."""
        if ref is None:
            return None
        try:
            cls = self.registry.get(kind, ref.name)
        except SsgaError as exc:
            self.problems.append(f"{format_loc((*at, 'name'))}: {exc}")
            return None
        self._classes[id(ref)] = cls
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
            self.problems.extend(pydantic_problems(exc, at))
            return None
        if self.base_dir is not None:
            relative = {k: self.base_dir / v for k, v in config if isinstance(v, Path) and not v.is_absolute()}
            config = config.model_copy(update=relative) if relative else config
        return ResolvedStage(kind, cls, config)

    def variants(self, config: VariantsConfig, available: frozenset[Data] | None = None, at: tuple[str | int, ...] = ()) -> list[ResolvedVariant]:
        """Every variant of ``config`` with its stages; problems are recorded, not raised.

        Args:
            available: what the workspace's real views carry, to check each binding
                against; ``None`` checks the stages against each other only.
        """
        defaults = {kind: self.stage(getattr(config.stages, kind), kind, (*at, "stages", kind)) for kind in PIPELINE_KIND_NAMES}
        variants: list[ResolvedVariant] = []
        labels: dict[str, int] = {}
        for i, spec in enumerate(config.variants):
            here = (*at, "variants", i)
            try:
                variant = parse_variant(spec.variant)
            except SsgaError as exc:
                self.problems.append(f"{format_loc((*here, 'variant'))}: {exc}")
                continue
            stages: dict[str, ResolvedStage] = {}
            classes: dict[str, type[Stage]] = {}
            for kind in variant.kinds():
                ref = getattr(spec, kind)
                if ref is None:
                    ref = getattr(config.stages, kind)
                    stage = defaults[kind]
                    if ref is None:
                        self.problems.append(f"{format_loc((*here, kind))}: {variant} needs a {kind}; bind one here or in [stages]")
                else:
                    stage = self.stage(ref, kind, (*here, kind))
                if stage is not None:
                    stages[kind] = stage
                if ref is not None and id(ref) in self._classes:
                    classes[kind] = self._classes[id(ref)]
            # Check the binding whenever every class is known, even if some parameters were
            # wrong, so one run reports both kinds of problem.
            if len(classes) == len(variant.order):
                views = available if available is not None else frozenset(Data)
                self.problems.extend(f"{format_loc(here)}: {p}" for p in check_binding(variant, classes, views))
            if len(stages) < len(variant.order):
                continue
            label = spec.label or table_label(variant, stages["parser"].cls if "parser" in stages else None, stages["descriptor"].cls)
            caveats = sorted({c for s in stages.values() if (c := s.cls.caveat(s.config))})
            if caveats:
                label += f" [{', '.join(caveats)}]"
            if label in labels:
                self.problems.append(
                    f"{format_loc((*here, 'variant'))}: label {label!r} is also variants[{labels[label]}]'s; "
                    f"give one a preset number (e.g. {variant.order}2) or a label"
                )
            labels.setdefault(label, i)
            variants.append(ResolvedVariant(variant, label, stages))
        return variants

    def raise_problems(self, source: str) -> None:
        if self.problems:
            raise ConfigError(source, self.problems)


def resolve_stage(
    kind: str, ref: Mapping[str, Any], registry: Registry, *, base_dir: Path | None = None, source: str = "<options>"
) -> ResolvedStage:
    """Resolve one ``{name = ..., ...}`` stage reference (command-line options, a plugin's tests)."""
    kind_named(kind)
    try:
        parsed = REF_TYPES[kind].model_validate(ref)
    except ValidationError as exc:
        raise ConfigError(source, pydantic_problems(exc, (kind,))) from None
    resolver = Resolver(registry, base_dir)
    stage = resolver.stage(parsed, kind, (kind,))
    resolver.raise_problems(source)
    assert stage is not None
    return stage


def resolve_variants(path: str | Path, registry: Registry, data: dict[str, Any] | None = None) -> list[ResolvedVariant]:
    """The variants a config file binds, with their stages (its other sections are not read).

    ``data``: the file's contents when the caller has read them already (with a plugin's
    layers applied: :func:`ssga_core.hookspecs.ssga_read_config`); else the file is read.
    """
    path = Path(path)
    if data is None:
        data = read_toml(path)
    try:
        config = VariantsConfig.model_validate({k: data[k] for k in ("stages", "variants") if k in data})
    except ValidationError as exc:
        raise ConfigError(str(path), pydantic_problems(exc)) from None
    resolver = Resolver(registry, path.parent)
    variants = resolver.variants(config)
    resolver.raise_problems(str(path))
    return variants


def stage_schemas(registry: Registry, defs: dict[str, Any]) -> None:
    """Put in ``defs`` (a JSON schema's ``$defs``) each kind's reference as the installed plugins' own schemas."""
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
