"""The stage kinds: the one table every other part of ssga derives its list of kinds from.

A kind is a role a plugin's class can fill. The registry indexes classes by kind and
checks them against the kind's base class, config references (``parser = { name =
... }``) exist per kind, the variant grammar's letters are the kinds that have one,
and the CLI and the contract tests list kinds in this order.
"""

from __future__ import annotations

from dataclasses import dataclass

from ssga_core.stages import Descriptor, Fuser, Parser, Stage, Synthesizer, WorkspaceSource


@dataclass(frozen=True)
class StageKind:
    """One kind of stage.

    Attributes:
        base: the class every implementation subclasses; its ``kind`` is the kind's name.
        hook: the hook (:mod:`ssga_core.hookspecs`) that registers implementations.
        verb: what an implementation does, in messages and listings.
        letter: the kind's letter in a variant order (``P``, ``D``, ``S``), or ``None``
            for kinds that are not steps of the pipeline.
    """

    base: type[Stage]
    hook: str
    verb: str
    letter: str | None = None

    @property
    def name(self) -> str:
        return self.base.kind


KINDS: tuple[StageKind, ...] = (
    StageKind(Parser, "ssga_register_parsers", "parse", "P"),
    StageKind(Descriptor, "ssga_register_descriptors", "describe", "D"),
    StageKind(Synthesizer, "ssga_register_synthesizers", "synthesize", "S"),
    StageKind(Fuser, "ssga_register_fusers", "fuse"),
    StageKind(WorkspaceSource, "ssga_register_workspaces", "open"),
)
"""Every kind, in the order listings use."""

PIPELINE_KINDS: tuple[StageKind, ...] = tuple(k for k in KINDS if k.letter)
"""The kinds a variant order is made of, P, D and S."""

KIND_NAMES: tuple[str, ...] = tuple(k.name for k in KINDS)
PIPELINE_KIND_NAMES: tuple[str, ...] = tuple(k.name for k in PIPELINE_KINDS)


def kind_named(name: str) -> StageKind:
    for k in KINDS:
        if k.name == name:
            return k
    raise KeyError(f"no stage kind {name!r}; kinds: {', '.join(KIND_NAMES)}")


def kind_of_letter(letter: str) -> StageKind:
    for k in PIPELINE_KINDS:
        if k.letter == letter:
            return k
    raise KeyError(f"no stage kind with letter {letter!r}")
