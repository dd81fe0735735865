"""Experiment configs: one TOML file, validated in two steps, every problem reported at once.

Step 1 checks the file's shape against :class:`ExperimentConfig`. Step 2 resolves every
stage reference through the core's :class:`~ssga_core.config.Resolver` (the one path from
a config to stage instances: plugin parameters validated by the plugin's own ``Config``,
relative paths taken from the config file's folder), parses each variant and checks each
binding against its plugins and the workspace's views. A minimal config::

    variants = ["PDS", "PSD", "SPD", "DSP", "PD", "DS", "SD", "D"]

    [workspace]
    name = "procedural"

    [stages]
    parser = { name = "slico" }
    descriptor = { name = "dense-sift" }
    synthesizer = { name = "depth-warp" }

A section left out (``workspace``, ``fuser``) is taken from the packaged
``configs/defaults.toml``: ssga's code names no particular plugin.

Whatever validates must run: every number is bounded to what the runner can do, and
non-finite floats are refused.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, ClassVar, Literal

from pydantic import ConfigDict, Field, ValidationError

from ssga_core.config import REF_TYPES, ResolvedStage, ResolvedVariant, Resolver, Strict, VariantsConfig, pydantic_problems, read_toml, stage_schemas
from ssga_core.errors import ConfigError
from ssga_core.plugins import Registry
from ssga_bench.execution import ExecutionConfig
from ssga_bench.io import path_error, path_errors
from ssga_bench.protocol import ProtocolConfig

WorkspaceRef = REF_TYPES["workspace"]
FuserRef = REF_TYPES["fuser"]


def packaged_config(name: str) -> Path:
    """Path of a config shipped with ssga-bench (``demo.toml``, ``bench.toml``, ``paper.toml``, ``defaults.toml``)."""
    return Path(str(resources.files("ssga_bench") / "configs" / name))


class TrainingConfig(Strict):
    """The per-variant GCN place classifier and its training data."""

    model_config = ConfigDict(allow_inf_nan=False)
    added_since: ClassVar[frozenset[str]] = frozenset(
        {"match_whiten", "match_whiten_parts", "match_whiten_variants", "match_category_penalty", "match_category_min_score"}
    )

    classifier: Literal["gcn", "graph-match"] = Field(
        default="gcn",
        description="Each variant's place classifier: 'gcn' (the paper's graph convolutional network) or 'graph-match' "
        "(a query takes the class of the training graphs it matches best, whole image and parts matched part to part; "
        "nothing to train: ssga_bench.matching).",
    )
    match_whole: float = Field(
        default=0.5,
        ge=0.0,
        le=1.0,
        description="classifier = 'graph-match': the whole image's share of a match; the parts' is the rest.",
    )
    match_layout: float = Field(
        default=0.0,
        ge=0.0,
        le=1.0,
        description="classifier = 'graph-match': the share of the part match that weighs each pair of parts by how near they "
        "stand in their images (parts in place); the rest matches parts wherever they stand.",
    )
    layout_sigma: float = Field(
        default=0.3,
        gt=0.0,
        le=10.0,
        description="classifier = 'graph-match', match_layout > 0: how far apart two parts may stand and still count as in place "
        "(a Gaussian's sigma, in image widths and heights).",
    )
    match_standardise: bool = Field(
        default=False,
        description="classifier = 'graph-match': standardise each query part's matches over the training graphs before "
        "they are averaged, so every part has an equal say, not most of it the parts whose similarities spread widest "
        "(standardised parts).",
    )
    match_drawn: bool = Field(
        default=False,
        description="classifier = 'graph-match': weigh each query part's match with a training graph by how much of that "
        "graph's image was drawn where the part stands, and each training part's by how much was drawn under it, so a "
        "pseudo-view with holes is judged on what it shows (parts judged where drawn).",
    )
    match_drawn_prior: float = Field(
        default=0.0,
        ge=0.0,
        le=1000.0,
        description="match_drawn: how many of the query's parts' worth of each training graph's plain mean its drawn-weighted "
        "mean starts from, so a pseudo-view drawn under only a few of the query's parts is not judged on those few alone "
        "(0: weighted by what was drawn alone).",
    )
    match_burst: float | None = Field(
        default=None,
        ge=-1.0,
        le=1.0,
        description="classifier = 'graph-match': parts of one image whose cosine similarity exceeds this repeat one "
        "another (a brick wall cut into many parts) and share a vote, on the query's side and each training graph's, so "
        "one texture does not decide a match by its count of parts (repeated parts counted once); unset: every part votes.",
    )
    match_burst_power: float = Field(
        default=1.0,
        ge=0.0,
        le=4.0,
        description="match_burst: a part with n repeats in its image (itself included) votes n ** -this (1: they share one "
        "vote; 0.5: the square root of their count).",
    )
    match_whiten: float | None = Field(
        default=None,
        gt=0.0,
        le=1000.0,
        description="classifier = 'graph-match': compare whole images after whitening them by the training graphs' "
        "scatter within each class (what synthesis varies among one place's graphs counts less), the covariance shrunk "
        "by this times its mean eigenvalue (the whole image whitened); unset: plain cosine, as the nearest-neighbour row.",
    )
    match_whiten_parts: bool | Literal["carried"] = Field(
        default=False,
        description="match_whiten: compare the parts in the same whitened space as the whole images (each side's parts "
        "less the training parts' mean); 'carried': whiten them instead by how one real part varies among its class's "
        "graphs (the part of the class's real view and what each pseudo-view carried of it through S: PDS, PSD), "
        "and as true where the training graphs carry none (SPD); off: the parts' plain cosines.",
    )
    match_whiten_variants: Literal["all", "synthesized"] = Field(
        default="all",
        description="match_whiten: the variants it whitens: 'all', or 'synthesized', only those whose descriptor sees "
        "the synthetic views (S before D: SPD, PSD, SD), where what varies among one place's graphs is what S drew; "
        "those that carry the real view's own features through S (PDS, DSP, DS) and those without S stay plain, "
        "and keep their keys.",
    )
    match_category_penalty: float = Field(
        default=0.0,
        ge=0.0,
        le=10.0,
        description="classifier = 'graph-match', for a parser that names each part's category (cascade-seg, detic, "
        "semantic): lower the cosine of a query part and a training part of different categories by this before their "
        "best twins are taken, where the other side holds a part of the category (2: a part's twin is of its own "
        "category wherever the other side has one); 0: parts matched whatever their category. Pays where the "
        "categories are right (ground truth), not with cascade-seg's light network. Other variants ignore it and "
        "keep their keys.",
    )
    match_category_min_score: float = Field(
        default=0.0,
        ge=0.0,
        le=1.0,
        description="match_category_penalty: count a part's category only where the parser scored it this high or "
        "more (Regions.scores: cascade-seg's mean probability of the class over the part, Detic's score); parts below "
        "are matched whatever their category. 0: every category counts. Parsers that give no scores (ground truth) "
        "keep every category. Ignored, and out of the key, where the penalty is 0 or the parser names no categories.",
    )
    hidden: int = Field(default=256, gt=0, le=8192, description="Hidden width of the GCN.")
    layers: int = Field(default=2, ge=1, le=32, description="Graph-convolution layers.")
    dropout: float = Field(default=0.0, ge=0.0, lt=1.0, description="Dropout on the hidden node states and on the pooled state.")
    readout: Literal["image+parts", "mean", "weighted"] = Field(
        default="image+parts",
        description="'image+parts': the whole image's state beside the weighted mean of the parts' states; 'mean' / "
        "'weighted': all nodes pooled by count / by node weight (whole image 1, parts 1/K).",
    )
    node_weights: Literal["input", "readout"] = Field(
        default="input",
        description="Where the node weights (whole image 1, parts 1/K, paper 3.2) act: 'input' scales the standardised "
        "node features by them (the paper); 'readout' only weighs the parts in the readout.",
    )
    head: Literal["linear", "cosine"] = Field(
        default="linear",
        description="The GCN's last layer: 'linear' (the paper's) or 'cosine', a scaled cosine to one prototype per class, "
        "each started at the mean pooled state of the class's training graphs.",
    )
    epochs: int = Field(default=200, gt=0, le=100_000, description="Most epochs; early stopping should end training before.")
    batch_size: int = Field(default=64, gt=0, le=1_000_000, description="Graphs per optimiser step.")
    threads: int = Field(
        default=1,
        ge=0,
        le=1024,
        description="Torch threads while training (0: torch's default, every core). Two are ~1.5x faster on an idle 2-core "
        "machine and several times slower while another process holds a core.",
    )
    lr: float = Field(default=1e-3, gt=0.0, le=10.0)
    weight_decay: float = Field(default=5e-4, ge=0.0, le=10.0, description="L2 penalty on the weights (Adam's weight_decay).")
    patience: int = Field(
        default=20,
        gt=0,
        le=100_000,
        description="Epochs without a better validation loss (training loss, lacking one) before stopping.",
    )
    validation_fraction: float = Field(default=0.2, gt=0.0, lt=1.0, description="Share of training graphs held out for early stopping.")
    synthetic_per_class: int = Field(default=4, gt=0, le=1000, description="Pseudo-training graphs per class (variants with S).")
    synthetic_per_level: int = Field(
        default=0,
        ge=0,
        le=1000,
        description="poses = 'class': of each class's synthetic_per_class poses, up to this many (at most a third) kept for "
        "each of L2 and L3, the levels its test views have: drawn as test views are, 1-2% of poses are at L3 and most "
        "classes get none like their L3 test views. 0: every pose drawn as test views are.",
    )
    poses: Literal["class", "canonical"] = Field(
        default="class",
        description="Where pseudo-views stand: 'class' draws them over the region of poses that belong to the class, the "
        "way test views are drawn; 'canonical' (the paper's reading) puts the first at the class's training viewpoint and "
        "the rest jittered around it.",
    )
    jitter_m: float = Field(default=0.15, ge=0.0, le=5.0, description="poses = 'canonical': jittered copies move up to this far, metres.")
    jitter_deg: float = Field(default=5.0, ge=0.0, le=180.0, description="...and turn up to this much, degrees.")
    sources: Literal["seen", "own"] = Field(
        default="seen",
        description="Which real views a pseudo-view is synthesized from: 'own' (the paper) its cell's one real view; 'seen' "
        "its cell's view fused with every other cell's real view that sees its content (see min_source_coverage).",
    )
    max_sources: int = Field(default=4, ge=1, le=64, description="sources = 'seen': at most this many real views per pseudo-view.")
    min_source_coverage: float = Field(
        default=0.2,
        ge=0.0,
        le=1.0,
        description="sources = 'seen': another cell's real view joins if it sees at least this share of the floor the pseudo-view sees.",
    )
    parse_invented: bool = Field(
        default=False,
        description="An order that parses before S and describes after it (PSD) also parses what the synthesizer drew where "
        "no real view's part landed (a room it filled in), and adds those regions as parts; false: those pixels belong "
        "to no part, the paper's reading (ssga_core.pipeline).",
    )
    describe_invented: bool = Field(
        default=False,
        description="An order that describes before S (PDS, DSP, DS) also describes what the synthesizer drew where no "
        "real view's pixel landed (a room it filled in), PDS parsing it into parts first; false: only the real view's "
        "features are carried, the paper's reading (ssga_core.pipeline).",
    )
    join_split_parts: bool = Field(
        default=False,
        description="An order that parses before S (PDS, PSD), with a parser whose regions are connected pieces of one "
        "category (cascade-seg), joins the parts of one category that touch in the synthetic view, as the parser cuts "
        "a query: a part the real view's frame cut off meets what the synthesizer drew beside it; false: each carried "
        "part stays one node, the paper's reading (ssga_core.pipeline).",
    )
    real_for_every_class: bool = Field(
        default=True,
        description="Variants without S train each class of a cell on the cell's real graph (the paper: they 'simply use "
        "available training images as they are'); false trains them on the real classes only.",
    )
    seed: int = Field(default=0, ge=0, lt=2**32, description="Seed of the jittered poses and of the GCN's training.")


class EnsembleConfig(Strict):
    """How the variants are fused and what the report sets beside them."""

    model_config = ConfigDict(allow_inf_nan=False)

    members: Literal["all", "validation"] = Field(
        default="all",
        description="Variants fused: 'all' (the paper), or those chosen on the validation views by forward selection "
        "(needs protocol.val_per_class > 0; the other is reported beside it).",
    )
    selection: Literal["views", "levels"] = Field(
        default="views",
        description="What forward selection of the members maximises on the validation views: 'views', their MRR (each "
        "level weighs by its share of the views, L1 about three quarters); 'levels', the mean of the difficulty levels' "
        "MRRs, each level counting as one column of Table 1 does (docs/experiments.md, 'Other ways of choosing the members').",
    )
    oracle: list[str] = Field(
        default_factory=lambda: ["SD"],
        max_length=16,
        description="Variants (orders, e.g. 'SD') also trained on true renders at the same poses, as an oracle row, "
        "where the workspace renders any pose. SD describes the whole true render; DS only what the landmark saw of it.",
    )
    queries_to_draw: int = Field(default=10, ge=0, le=10_000, description="Pictures of sample queries beside their classes' views.")
    also: list[FuserRef] = Field(  # type: ignore[valid-type]
        default_factory=list,
        max_length=8,
        description="More fusion rules reported beside the ensemble, each over every variant, e.g. [{ name = 'stacking' }]: "
        "a rule learned on the validation views (needs protocol.val_per_class > 0) beside the paper's reciprocal-rank fusion. "
        "A rule that does not learn is also reported over the members chosen for it on the validation views.",
    )


class PriorConfig(Strict):
    """What every row's class scores are multiplied by before fusion and evaluation (ssga_bench.heading)."""

    model_config = ConfigDict(allow_inf_nan=False)

    heading: Literal["none", "manhattan"] = Field(
        default="none",
        description="'manhattan': a heading prior read from each view's straight horizontal edges (their vanishing point "
        "gives the heading modulo 90 degrees against the room's directions, which the real views' known headings fix), "
        "applied to every row alike; 'none': the paper's scores (docs/experiments.md, 'A heading prior from the room's lines').",
    )
    sigma_deg: float = Field(default=2.0, gt=0.0, le=45.0, description="How far, in degrees, a heading estimate may stray outside a class's window.")
    mix: float = Field(
        default=0.05, ge=0.0, le=1.0, description="Share of the prior spread over every class, so that a wrong estimate lowers the true class without ruling it out."
    )


class ExperimentConfig(VariantsConfig):
    """A whole experiment: where views come from, the variants and their stages, training, fusion."""

    preset: str | None = Field(
        default=None,
        description="Start from a packaged experiment (demo, bench, paper: `ssga config presets`); the file's own "
        "keys override it, section by section (a section naming another plugin replaces the preset's).",
    )
    workspace: WorkspaceRef | None = Field(default=None, description="The workspace source [default: defaults.toml's].")  # type: ignore[valid-type]
    protocol: ProtocolConfig = ProtocolConfig()
    training: TrainingConfig = TrainingConfig()
    fuser: FuserRef | None = Field(default=None, description="The late-fusion rule [default: defaults.toml's].")  # type: ignore[valid-type]
    ensemble: EnsembleConfig = EnsembleConfig()
    prior: PriorConfig = PriorConfig()
    execution: ExecutionConfig = Field(
        default=ExecutionConfig(), description="Where the independent work runs (serial, local processes, Ray); results do not depend on it."
    )
    output: Path = Field(default=Path("runs/experiment"), description="Folder for caches, checkpoints and reports (relative: to the current directory).")


@dataclass(frozen=True)
class Experiment:
    """A validated config with every stage resolved."""

    config: ExperimentConfig
    workspace: ResolvedStage
    variants: list[ResolvedVariant]
    fuser: ResolvedStage
    also: list[ResolvedStage] = field(default_factory=list)
    """The fusers reported beside the ensemble (``ensemble.also``)."""
    source: str = "<config>"
    base_dir: Path | None = None
    """The folder relative paths of the config were taken from (the config file's)."""


def packaged_presets() -> list[str]:
    """The packaged experiments a config can start from (``preset = "paper"``) or a command can name."""
    return sorted(p.name.removesuffix(".toml") for p in resources.files("ssga_bench").joinpath("configs").iterdir() if p.name.endswith(".toml") and p.name != "defaults.toml")


def config_path(given: str | Path) -> Path:
    """``given`` if it is a file, else the packaged experiment it names (``paper`` or ``paper.toml``)."""
    path = Path(given)
    if path.exists() or path.parent != Path("."):
        return path
    name = path.name.removesuffix(".toml")
    return packaged_config(f"{name}.toml") if name in packaged_presets() else path


def with_preset(data: dict[str, Any], source: str, seen: tuple[str, ...] = ()) -> dict[str, Any]:
    """``data`` over the packaged experiment its ``preset`` names (itself over its own preset, if it
    names one): top-level keys replace the preset's; a section (table) is merged key by key, unless it
    names another plugin (``name``), which replaces it."""
    name = data.get("preset")
    if name is None:
        return data
    if not isinstance(name, str) or name not in packaged_presets():
        raise ConfigError(source, [f"preset: {name!r} is not a packaged experiment; known: {', '.join(packaged_presets())}"])
    if name in seen:
        raise ConfigError(source, [f"preset: {name!r} names itself through {' -> '.join((*seen, name))}"])
    merged = with_preset(read_toml(packaged_config(f"{name}.toml")), f"{name}.toml", (*seen, name))
    for key, value in data.items():
        base = merged.get(key)
        same_plugin = isinstance(base, dict) and isinstance(value, dict) and value.get("name", base.get("name")) == base.get("name")
        merged[key] = {**base, **value} if same_plugin else value  # type: ignore[dict-item]
    return merged


def read_experiment(path: str | Path) -> tuple[dict[str, Any], Path]:
    """An experiment config file (or a packaged one by name) with its ``preset`` applied, and the file it is."""
    path = config_path(path)
    return with_preset(read_toml(path), str(path)), path


@path_errors()
def load_experiment(path: str | Path, registry: Registry) -> Experiment:
    """Read and validate an experiment config file (or a packaged one by name); raise :class:`ConfigError` with every problem."""
    data, path = read_experiment(path)
    return validate_experiment(data, registry, source=str(path), base_dir=path.parent)


def _defaults() -> dict[str, Any]:
    return read_toml(packaged_config("defaults.toml"))


def validate_experiment(data: dict[str, Any], registry: Registry, *, source: str = "<config>", base_dir: Path | None = None) -> Experiment:
    """Validate a config mapping (see the module docstring).

    Args:
        base_dir: relative paths in stage parameters are taken from this folder, the
            config file's; ``None`` leaves them relative to the current directory.
    """
    try:
        config = ExperimentConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(source, pydantic_problems(exc)) from None
    defaults = _defaults()
    resolver = Resolver(registry, base_dir)
    # A section taken from the defaults is the package's, so its paths are not the config file's.
    packaged = Resolver(registry)
    workspace = (
        resolver.stage(config.workspace, "workspace", ("workspace",))
        if config.workspace is not None
        else packaged.stage(WorkspaceRef.model_validate(defaults["workspace"]), "workspace", ("defaults.toml", "workspace"))
    )
    fuser = (
        resolver.stage(config.fuser, "fuser", ("fuser",))
        if config.fuser is not None
        else packaged.stage(FuserRef.model_validate(defaults["fuser"]), "fuser", ("defaults.toml", "fuser"))
    )
    also = [resolver.stage(ref, "fuser", ("ensemble", "also", i)) for i, ref in enumerate(config.ensemble.also)]
    resolver.problems.extend(packaged.problems)
    resolver.problems.extend(_fusion_problems(config, fuser, also))
    if workspace is not None:
        try:
            missing = workspace.cls.missing(workspace.config)
        except OSError as exc:  # a path the system refuses to look at (too long, through a file): the CLI's one line
            raise path_error(exc) from None
        resolver.problems.extend(f"workspace.{problem}" for problem in missing)
    variants = resolver.variants(config, available=workspace.cls.carries(workspace.config) if workspace else None)
    resolver.raise_problems(source)
    assert workspace is not None and fuser is not None
    return Experiment(
        config=config, workspace=workspace, variants=variants, fuser=fuser, also=[f for f in also if f is not None], source=source, base_dir=base_dir
    )


def _fusion_problems(config: ExperimentConfig, fuser: ResolvedStage | None, also: list[ResolvedStage | None]) -> list[str]:
    """A fuser learned on validation views without any, or members chosen for one that weighs its own."""
    problems = []
    named = [("fuser", fuser)] + [(f"ensemble.also.{i}", f) for i, f in enumerate(also)]
    for at, stage in named:
        if stage is not None and getattr(stage.cls, "learns", False) and config.protocol.val_per_class == 0:
            problems.append(f"{at}: fuser {stage.name!r} is learned on the validation views; set protocol.val_per_class > 0")
    if fuser is not None and getattr(fuser.cls, "learns", False) and config.ensemble.members == "validation":
        problems.append(f"ensemble.members: fuser {fuser.name!r} weighs its members itself; members = 'validation' is for a rule that does not learn, use 'all'")
    return problems


def experiment_schema(registry: Registry) -> dict[str, Any]:
    """JSON schema of the config file, with each stage reference listing the installed plugins' own schemas."""
    schema = ExperimentConfig.model_json_schema()
    stage_schemas(registry, schema.setdefault("$defs", {}))
    return schema
