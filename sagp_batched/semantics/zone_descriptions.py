"""Each zone of a cloud described in words for the rating prompt: how much of the object it holds and where
it is (the prompt in ``rating.prompt`` takes these words, a rater nothing else of the zones)."""
from __future__ import annotations

from .zones import ObjectFacts, ZoneDecomposition, ZoneFacts

_HALF_WORDS = {"left": "robot's left", "right": "robot's right", "front": "side facing the robot", "back": "side away from the robot"}


def describe_zones(decomposition: ZoneDecomposition) -> dict[str, str]:
    """A short geometric description of every zone that holds points, for the rating prompt.

    A protrusion is described by where it is and how it sticks out: its share of the points, its
    height band on the object, the side it sticks out on and how far beyond the body.
    """
    facts = decomposition.facts()
    descriptions = {zone.name: _zone_description(zone, facts) for zone in facts.zones}
    if facts.degenerate is not None:
        descriptions = {k: f"{v} (degenerate cloud: {facts.degenerate})" for k, v in descriptions.items()}
    return descriptions


def _zone_description(zone: ZoneFacts, facts: ObjectFacts) -> str:
    share = f"{zone.name}: {100.0 * zone.point_count / facts.n_points:.0f}% of points"
    if zone.kind == "side":
        return f"{share}, the half on the {_HALF_WORDS[zone.name]}"
    if zone.kind == "length":
        return f"{share}, {_length_zone_words(zone, facts)}"
    height_cm = 100.0 * facts.height_m
    if zone.kind == "vertical":
        return f"{share}, {zone.name} {100.0 * zone.height_m:.1f} cm of the object's {height_cm:.1f} cm height"
    low_cm, high_cm = (100.0 * metres for metres in zone.band_above_lowest_m)
    reference = "the body's side" if facts.protrusion_rule == "body" else "the body's typical extent"
    return (
        f"{share}, a part that sticks out on the {zone.side} side, {low_cm:.1f} to {high_cm:.1f} cm above the object's "
        f"lowest point ({height_cm:.1f} cm tall), reaching {100.0 * zone.beyond_body_m:.1f} cm beyond {reference}"
    )


def _length_zone_words(zone: ZoneFacts, facts: ObjectFacts) -> str:
    """Where a third along a lying object's length is, and how wide it is across."""
    length_cm, width_cm = 100.0 * facts.length_m, 100.0 * zone.width_m
    if zone.name == "middle":
        return f"the middle third of the object's {length_cm:.1f} cm length (it lies on the table), {width_cm:.1f} cm across"
    wider = "wider" if zone.name == "wide_end" else "narrower"
    return f"the {wider} end, one third of the object's {length_cm:.1f} cm length (it lies on the table), {width_cm:.1f} cm across"
