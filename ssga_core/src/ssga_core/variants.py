"""Pipeline variants: which stages run, in which order.

A variant is an ordering of a subset of the stages P (parse), D (describe) and
S (synthesize) that contains D, optionally followed by a preset number that tells
apart two bindings of one order (the paper's ``SPD1`` and ``SPD2``). Grammar, in EBNF:

.. code-block:: ebnf

    variant = order , [ preset ] ;
    order   = stage , { stage } ;     (* each stage at most once; D must be one of them *)
    stage   = "P" | "D" | "S" ;
    preset  = nonzero digit , { digit } ;      (* at most 6 digits *)
    nonzero digit = "1" | ... | "9" ;  digit = "0" | nonzero digit ;   (* ASCII only *)

So there are 11 orders: ``D``; ``PD DP SD DS``; ``PDS PSD SPD SDP DPS DSP``. The paper
uses eight of them (:data:`PAPER_ORDERS`), one from each equivalence class: swapping a
``P`` and a ``D`` that are next to each other changes nothing (parsing and describing
the same image commute), so ``DP = PD``, ``DPS = PDS`` and ``SDP = SPD``.

What each order *means* (what each stage receives and hands on) is written once, in
:mod:`ssga_core.pipeline`. This module is the syntax plus the rules a bound variant's
plugins must satisfy, checked by :func:`check_binding` before anything runs.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any
from itertools import permutations

from ssga_core.data import VIEW_DATA, Data
from ssga_core.errors import VariantSyntaxError
from ssga_core.kinds import PIPELINE_KIND_NAMES, PIPELINE_KINDS
from ssga_core.stages import Stage

STAGES = tuple(k.letter for k in PIPELINE_KINDS)
STAGE_KINDS = {k.letter: k.name for k in PIPELINE_KINDS}
STAGE_VERBS = {k.letter: k.verb for k in PIPELINE_KINDS}
DIGITS = "0123456789"
"""The grammar's digits: ASCII only (``str.isdigit`` also accepts ``²`` and ``٣``)."""
MAX_PRESET_DIGITS = 6
PAPER_ORDERS = ("PDS", "PSD", "SPD", "DSP", "PD", "DS", "SD", "D")
"""The eight orders of the paper's §3.2, in its order."""


@dataclass(frozen=True)
class Variant:
    """A parsed variant string: an order and an optional preset number."""

    order: str
    preset: int | None = None

    def __str__(self) -> str:
        return self.order + ("" if self.preset is None else str(self.preset))

    @property
    def query_order(self) -> str:
        """What runs on a real query image: the order without S (P and D only), canonical."""
        return canonical_order(self.order.replace("S", ""))

    @property
    def canonical(self) -> str:
        """The paper's representative of this order's equivalence class."""
        return canonical_order(self.order)

    @property
    def in_paper(self) -> bool:
        return self.order in PAPER_ORDERS

    @property
    def synthesizes(self) -> bool:
        return "S" in self.order

    @property
    def describes_carried_parts(self) -> bool:
        """Parses before S and describes after it (PSD): the parts are carried through synthesis and
        described on the synthetic view, so they are the only ones that can take in what S drew
        where no part landed (``BoundVariant.parse_invented``)."""
        o = self.order
        return all(c in o for c in "PSD") and o.index("P") < o.index("S") < o.index("D")

    @property
    def describes_before_synthesis(self) -> bool:
        """Describes the real view and carries its local features through S (PDS, DSP, DS): only
        they leave undescribed what S drew where no source pixel landed (``BoundVariant.describe_invented``)."""
        o = self.order
        return "S" in o and o.index("D") < o.index("S")

    @property
    def describes_synthesized_views(self) -> bool:
        """Synthesizes before it describes (SPD, PSD, SD): its descriptor sees the synthetic views
        themselves, so what differs among one place's pseudo-views is what S drew differently."""
        o = self.order
        return "S" in o and o.index("S") < o.index("D")

    @property
    def carries_parts(self) -> bool:
        """Parses before S (PDS, PSD): the real view's parts are carried through synthesis, where
        its frame's edge may cut one of them in two (``BoundVariant.join_split_parts``)."""
        o = self.order
        return "P" in o and "S" in o and o.index("P") < o.index("S")

    def kinds(self) -> list[str]:
        """The stage kinds this variant binds, in order of execution."""
        return [STAGE_KINDS[s] for s in self.order]


def parse_variant(text: str) -> Variant:
    """Parse a variant string; errors carry the 1-based column and the reason.

    >>> parse_variant("SPD2")
    Variant(order='SPD', preset=2)
    """
    if not isinstance(text, str):
        raise VariantSyntaxError(repr(text), 1, f"expected a string such as 'PDS', got {type(text).__name__}")
    i = 0
    seen: list[str] = []
    while i < len(text) and text[i] not in DIGITS:
        ch = text[i]
        col = i + 1
        if ch in STAGES:
            if ch in seen:
                raise VariantSyntaxError(text, col, f"stage {ch} ({STAGE_VERBS[ch]}) appears twice; each stage runs at most once")
            seen.append(ch)
        elif ch.upper() in STAGES:
            raise VariantSyntaxError(text, col, f"stages are upper-case: {ch.upper()!r}, not {ch!r} (did you mean {text.upper()!r}?)")
        elif ch.isspace():
            raise VariantSyntaxError(text, col, "spaces are not allowed inside a variant; write the stages together, e.g. 'PDS'")
        else:
            raise VariantSyntaxError(text, col, f"{ch!r} is not a stage; expected P (parse), D (describe) or S (synthesize)")
        i += 1
    if not seen:
        reason = "empty variant" if not text else "a variant starts with its stages"
        raise VariantSyntaxError(text, i + 1, f"{reason}; expected P (parse), D (describe) or S (synthesize)")
    if "D" not in seen:
        raise VariantSyntaxError(text, i + 1, "a variant must contain D (describe): without it no node has a feature")
    preset = None
    if i < len(text):
        if text[i] == "0":
            raise VariantSyntaxError(text, i + 1, "a preset number starts at 1")
        j = i
        while j < len(text) and text[j] in DIGITS:
            j += 1
        if j < len(text):
            raise VariantSyntaxError(text, j + 1, f"unexpected {text[j]!r} after the preset number {text[i:j]}")
        if j - i > MAX_PRESET_DIGITS:
            raise VariantSyntaxError(text, i + MAX_PRESET_DIGITS + 1, f"a preset number has at most {MAX_PRESET_DIGITS} digits")
        preset = int(text[i:j])
    return Variant(order="".join(seen), preset=preset)


def canonical_order(order: str) -> str:
    """Swap each adjacent ``DP`` to ``PD`` until none is left."""
    while "DP" in order:
        order = order.replace("DP", "PD")
    return order


def all_orders() -> list[str]:
    """Every valid order: the paper's eight first, then the rest by length."""
    orders = {"".join(p) for n in (1, 2, 3) for p in permutations(STAGES, n) if "D" in p}
    rest = sorted(orders - set(PAPER_ORDERS), key=lambda o: (len(o), o))
    return [*PAPER_ORDERS, *rest]


def equivalents(order: str) -> list[str]:
    """The other orders that build the same graphs as ``order``."""
    c = canonical_order(order)
    return [o for o in all_orders() if o != order and canonical_order(o) == c]


def requirements(order: str) -> dict[str, dict[Data, str]]:
    """What an order needs its plugins to produce, by stage kind, each with the reason."""
    need: dict[str, dict[Data, str]] = {name: {} for name in PIPELINE_KIND_NAMES}
    d = order.index("D")
    if "P" in order and d < order.index("P"):
        need["descriptor"][Data.LOCAL_FEATURES] = (
            "the image is described before it is parsed, so node features are pooled from local "
            "features at pixel positions"
        )
    if "S" in order:
        s = order.index("S")
        if d < s:
            need["descriptor"][Data.LOCAL_FEATURES] = (
                "the real image's description is carried into the synthetic view, which moves local "
                "features at pixel positions with the synthesizer's point map"
            )
        if d < s or ("P" in order and order.index("P") < s):
            need["synthesizer"][Data.POINT_MAP] = (
                "what was parsed or described before synthesis is carried into the synthetic view by "
                "the synthesizer's point map"
            )
    return need


def check_binding(variant: Variant, bound: Mapping[str, type[Stage] | None], available: frozenset[Data]) -> list[str]:
    """Why this variant cannot run with these plugins on views carrying ``available``; empty if it can.

    Args:
        variant: the parsed variant.
        bound: stage kind -> bound class (``None`` or missing if unbound).
        available: what the workspace's real views carry (:attr:`WorkspaceSource.produces`).
    """
    problems: list[str] = []
    for kind in variant.kinds():
        if bound.get(kind) is None:
            problems.append(f"{variant} needs a {kind}, and none is bound")
    if problems:
        return problems
    for kind, needs in requirements(variant.order).items():
        cls = bound.get(kind)
        for data, why in needs.items():
            if cls is not None and data not in cls.produces:
                problems.append(f"{variant} cannot use {kind} {cls.name!r}: {why}, and {cls.name!r} gives no {data}")
    # Follow what each view carries through the order: the real view first, then the
    # synthetic one (whose semantic ids the core warps from the real view, if it had any).
    have = set(available) & VIEW_DATA
    where = "real"
    on_real: set[str] = set()
    for stage in variant.order:
        cls = bound[STAGE_KINDS[stage]]
        assert cls is not None
        missing = (cls.consumes & VIEW_DATA) - have
        if missing:
            problems.append(f"{variant}: {cls.kind} {cls.name!r} needs {_names(missing)}, which the {where} view does not carry")
        if stage == "S":
            have = (set(cls.produces) & VIEW_DATA) | (have & {Data.SEMANTIC})
            where = "synthetic"
        elif where == "real":
            on_real.add(stage)
    # Queries are real images, parsed and described without synthesis.
    for stage in variant.query_order:
        cls = bound[STAGE_KINDS[stage]]
        assert cls is not None
        missing = (cls.consumes & VIEW_DATA) - (set(available) & VIEW_DATA)
        if missing and stage not in on_real:
            problems.append(f"{variant}: {cls.kind} {cls.name!r} needs {_names(missing)}, which real query views do not carry")
    return problems


def _names(data: set[Data] | frozenset[Data]) -> str:
    return " and ".join(sorted(d.value for d in data))


def order_rows() -> list[dict[str, Any]]:
    """One row per valid order: its stages, whether the paper uses it, its needs, its equivalents."""
    rows = []
    for order in all_orders():
        variant = parse_variant(order)
        rows.append(
            {
                "order": order,
                "stages": [STAGE_VERBS[s] for s in order],
                "in_paper": variant.in_paper,
                "query_path": variant.query_order,
                "synthesizes": variant.synthesizes,
                "needs": {kind: sorted(str(d) for d in data) for kind, data in requirements(order).items() if data},
                "equivalent_to": equivalents(order),
            }
        )
    return rows
