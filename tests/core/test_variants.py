"""The variant grammar, the enumeration of orders and the checks of bound plugins."""

from __future__ import annotations

import pytest

from ssga_core import Data, VariantSyntaxError, parse_variant
from ssga_core.testing.stages import PatchColour, RegionColour, ShiftWarp, StripesParser
from ssga_core.variants import PAPER_ORDERS, all_orders, canonical_order, check_binding, equivalents, requirements


@pytest.mark.parametrize(
    ("text", "order", "preset"),
    [
        ("D", "D", None),
        ("PD", "PD", None),
        ("DS", "DS", None),
        ("SD", "SD", None),
        ("PDS", "PDS", None),
        ("PSD", "PSD", None),
        ("SPD", "SPD", None),
        ("DSP", "DSP", None),
        ("DP", "DP", None),
        ("SPD1", "SPD", 1),
        ("SPD2", "SPD", 2),
        ("PDS12", "PDS", 12),
        ("PD123456", "PD", 123456),
    ],
)
def test_valid_variants(text, order, preset):
    v = parse_variant(text)
    assert (v.order, v.preset) == (order, preset)
    assert str(v) == text


@pytest.mark.parametrize(
    ("text", "column", "message"),
    [
        ("", 1, "empty variant"),
        ("PPD", 2, "stage P (parse) appears twice"),
        ("DSD", 3, "stage D (describe) appears twice"),
        ("XD", 1, "'X' is not a stage"),
        ("ps", 1, "stages are upper-case: 'P', not 'p'"),
        ("P D", 2, "spaces are not allowed"),
        ("PS", 3, "must contain D"),
        ("S", 2, "must contain D"),
        ("1D", 1, "starts with its stages"),
        ("SPD0", 4, "preset number starts at 1"),
        ("SPD1a", 5, "unexpected 'a' after the preset number 1"),
        ("PD-", 3, "'-' is not a stage"),
        ("PD²", 3, "'²' is not a stage"),  # str.isdigit() says yes; int() would not
        ("PD٣", 3, "'٣' is not a stage"),  # Arabic-Indic three: int() would read 3
        ("PD1234567", 9, "at most 6 digits"),
        ("PD3x", 4, "unexpected 'x' after the preset number 3"),
    ],
)
def test_invalid_variants_name_the_column_and_reason(text, column, message):
    with pytest.raises(VariantSyntaxError) as info:
        parse_variant(text)
    assert info.value.column == column
    assert message in info.value.reason
    assert str(info.value).startswith(f"invalid variant {text!r}: column {column}: ")


def test_a_long_variant_is_refused_in_one_short_line():
    # int() of 5000 digits would raise ValueError (its 4300-digit limit); the input is not echoed whole.
    with pytest.raises(VariantSyntaxError) as info:
        parse_variant("PD" + "9" * 5000)
    assert info.value.column == 9 and "at most 6 digits" in info.value.reason
    assert "\n" not in str(info.value) and len(str(info.value)) < 200


def test_lower_case_suggests_the_upper_case_variant():
    with pytest.raises(VariantSyntaxError, match="did you mean 'PDS'"):
        parse_variant("pds")


def test_non_strings_are_rejected():
    with pytest.raises(VariantSyntaxError, match="expected a string"):
        parse_variant(12)  # type: ignore[arg-type]


def test_enumeration_lists_all_eleven_orders_paper_first():
    orders = all_orders()
    assert len(orders) == len(set(orders)) == 11
    assert tuple(orders[:8]) == PAPER_ORDERS
    assert set(orders[8:]) == {"DP", "DPS", "SDP"}
    for order in orders:
        assert parse_variant(order).order == order


def test_the_papers_eight_are_exactly_one_per_equivalence_class():
    classes = {canonical_order(o) for o in all_orders()}
    assert classes == set(PAPER_ORDERS)
    assert equivalents("PD") == ["DP"]
    assert equivalents("SDP") == ["SPD"]
    assert equivalents("DPS") == ["PDS"]
    assert equivalents("DSP") == []  # S between D and P: they do not commute


@pytest.mark.parametrize(
    ("variant", "query"),
    [("PDS", "PD"), ("PSD", "PD"), ("SPD", "PD"), ("DSP", "PD"), ("DS", "D"), ("SD", "D"), ("D", "D")],
)
def test_queries_are_parsed_and_described_without_synthesis(variant, query):
    assert parse_variant(variant).query_order == query


def test_only_orders_that_parse_before_s_and_describe_after_it_describe_carried_parts():
    carried = [order for order in all_orders() if parse_variant(order).describes_carried_parts]
    assert carried == ["PSD"]


def test_synthesis_comes_before_or_after_description_in_every_order_with_s():
    after = {order for order in all_orders() if parse_variant(order).describes_synthesized_views}
    before = {order for order in all_orders() if parse_variant(order).describes_before_synthesis}
    assert {"SPD", "PSD", "SD"} <= after and {"PDS", "DSP", "DS"} <= before
    assert not after & before
    assert after | before == {order for order in all_orders() if "S" in order}


def test_requirements_follow_the_order():
    assert requirements("SPD") == {"parser": {}, "descriptor": {}, "synthesizer": {}}
    assert set(requirements("DSP")["descriptor"]) == {Data.LOCAL_FEATURES}
    assert set(requirements("PSD")["synthesizer"]) == {Data.POINT_MAP}
    assert set(requirements("PSD")["descriptor"]) == set()
    assert set(requirements("DP")["descriptor"]) == {Data.LOCAL_FEATURES}


ALL = frozenset(Data)
BOUND_LOCAL = {"parser": StripesParser, "descriptor": PatchColour, "synthesizer": ShiftWarp}
BOUND_REGION = {"parser": StripesParser, "descriptor": RegionColour, "synthesizer": ShiftWarp}


@pytest.mark.parametrize("order", all_orders())
def test_a_local_descriptor_runs_in_every_order(order):
    assert check_binding(parse_variant(order), BOUND_LOCAL, ALL) == []


@pytest.mark.parametrize(
    ("order", "ok"),
    [("D", True), ("PD", True), ("SD", True), ("PSD", True), ("SPD", True), ("DS", False), ("DSP", False), ("PDS", False), ("DP", False)],
)
def test_a_region_descriptor_cannot_be_carried_or_grouped(order, ok):
    problems = check_binding(parse_variant(order), BOUND_REGION, ALL)
    assert (problems == []) is ok
    if not ok:
        assert "cannot use descriptor 'test-region-colour'" in problems[0]
        assert "local-features" in problems[0]


def test_dsp_explains_why_it_needs_movable_features():
    (problem,) = check_binding(parse_variant("DSP"), BOUND_REGION, ALL)
    assert "carried into the synthetic view" in problem


def test_unbound_stages_are_reported():
    problems = check_binding(parse_variant("PDS"), {"descriptor": PatchColour}, ALL)
    assert problems == ["PDS needs a parser, and none is bound", "PDS needs a synthesizer, and none is bound"]


def test_a_synthesizer_needing_depth_fails_on_rgb_only_views():
    problems = check_binding(parse_variant("SD"), BOUND_LOCAL, frozenset({Data.RGB}))
    assert problems == ["SD: synthesizer 'test-shift' needs depth, which the real view does not carry"]


def test_a_parser_needing_semantics_is_checked_on_real_queries_too():
    class OracleParser(StripesParser):
        name = "oracle"
        consumes = frozenset({Data.RGB, Data.SEMANTIC})

    bound = {**BOUND_LOCAL, "parser": OracleParser}
    # Semantic ids of the real view are warped into the synthetic one, so SPD can parse it...
    assert check_binding(parse_variant("SPD"), bound, ALL) == []
    # ...but queries from a source without semantic ids cannot be parsed.
    problems = check_binding(parse_variant("SPD"), bound, frozenset({Data.RGB, Data.DEPTH}))
    assert any("synthetic view does not carry" in p for p in problems)
    assert any("real query views do not carry" in p for p in problems)
