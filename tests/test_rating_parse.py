"""Model answers are untrusted input: every malformed answer gets a typed, logged outcome."""
from __future__ import annotations

import json

import pytest

from sagp_batched.rating import parse_zone_rating
from sagp_batched.rating.prompt import answer_zone_names

GOOD = {
    "ratings": {"top": "dangerous", "middle": "acceptable", "bottom": "bad", "protrusion": "good"},
    "preferred": ["protrusion"],
    "avoid": ["top"],
    "approach": "side",
    "grasp_style": "hook",
    "max_tilt_deg": 15,
}
# The zones of a mug-like decomposition, as the rater hands them to the parser.
KNOWN_ZONES = answer_zone_names({"top": "", "middle": "", "bottom": "", "left": "", "protrusion_1": ""})


def parse(text: str):
    return parse_zone_rating(text, "openai", "test-model", "v-test", 0.1, 15.0, KNOWN_ZONES)


def test_a_clean_answer_validates_as_given():
    rating = parse(json.dumps(GOOD))
    assert rating.provenance.outcome == "ok" and rating.issues == ()
    assert rating.ratings["protrusion"] == "good" and rating.avoid == {"top"}
    assert rating.approach == "side" and rating.max_tilt_deg == 15.0 and rating.grasp_style == "hook"


def test_fenced_json_with_prose_is_repaired():
    rating = parse("Sure! Here is the rating:\n```json\n" + json.dumps(GOOD) + "\n```\nHope this helps.")
    assert rating.provenance.outcome == "repaired"
    assert rating.ratings == GOOD["ratings"]
    assert any("fence" in issue for issue in rating.issues)


def test_truncated_json_keeps_its_complete_members_only():
    text = json.dumps(GOOD)
    cut = text[: text.index('"bottom"') + len('"bottom": "ba')]
    rating = parse(cut)
    assert rating.provenance.outcome == "repaired"
    assert rating.ratings == {"top": "dangerous", "middle": "acceptable"}, "the half-written member is dropped"
    assert rating.preferred == frozenset() and rating.avoid == frozenset()
    assert any("truncated" in issue for issue in rating.issues)
    assert any("missing field 'avoid'" in issue for issue in rating.issues)


def test_unknown_zone_names_and_levels_are_dropped_not_guessed():
    answer = {**GOOD, "ratings": {**GOOD["ratings"], "handle": "good", "middle": "excellent"}, "preferred": ["handle", "protrusion"]}
    rating = parse(json.dumps(answer))
    assert "handle" not in rating.ratings and "middle" not in rating.ratings
    assert rating.preferred == {"protrusion"}
    assert "unknown zones in 'ratings' dropped: 1 (first 'handle')" in rating.issues
    assert "unknown zones in 'preferred' dropped: 1 (first 'handle')" in rating.issues
    assert "unknown levels in 'ratings' dropped: 1 (first 'excellent')" in rating.issues


def test_zones_outside_the_decomposition_are_dropped_though_in_the_vocabulary():
    rating = parse(json.dumps({**GOOD, "ratings": {"protrusion_2": "good", "right": "bad", "protrusion_1": "good"}}))
    assert rating.ratings == {"protrusion_1": "good"}
    assert "unknown zones in 'ratings' dropped: 2 (first 'protrusion_2')" in rating.issues


def test_missing_fields_take_their_neutral_values():
    rating = parse(json.dumps({"ratings": {"middle": "good"}}))
    assert rating.provenance.outcome == "repaired"
    assert rating.approach == "any" and rating.grasp_style == "any" and rating.max_tilt_deg is None
    assert rating.preferred == frozenset() and rating.avoid == frozenset()


def test_a_zone_both_preferred_and_avoided_is_kept_as_avoided():
    rating = parse(json.dumps({**GOOD, "preferred": ["protrusion", "top"], "avoid": ["top"]}))
    assert rating.avoid == {"top"} and rating.preferred == {"protrusion"}
    assert any("both preferred and avoided" in issue for issue in rating.issues)


@pytest.mark.parametrize(
    "text",
    ["", "I cannot help with that.", "V]oB}l\"XoBg}l#e]oBg}", "[1, 2, 3]", '{"ratings": {"handle": "good"}}', "{{{{"],
    ids=["empty", "prose", "garbage", "json-list", "nothing-valid", "broken"],
)
def test_unusable_answers_give_a_neutral_rating_marked_as_such(text, caplog):
    rating = parse(text)
    assert rating.is_neutral and rating.provenance.outcome == "neutral"
    assert rating.ratings == {} and rating.preferred == frozenset() and rating.avoid == frozenset()
    assert rating.approach == "any" and rating.max_tilt_deg is None
    assert rating.issues and rating.raw_text == text
    assert any("neutral" in record.message for record in caplog.records)


def test_approach_vectors_and_upright_constraints_are_normalised():
    rating = parse(json.dumps({**GOOD, "approach": [0, 0, -2], "max_tilt_deg": "upright"}))
    assert rating.approach == "vector" and rating.approach_vector_world == (0.0, 0.0, -1.0)
    assert rating.max_tilt_deg == 15.0
    bad = parse(json.dumps({**GOOD, "approach": [0, 0, 0], "max_tilt_deg": -4}))
    assert bad.approach == "any" and bad.max_tilt_deg is None and len(bad.issues) == 2
