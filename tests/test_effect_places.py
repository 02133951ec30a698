"""An effect's place as the user writes it (stiffness.elastic.effects.base.effect_place): the
colon spelling of ``simulate --effect`` and ``design --separate`` and the label spelling of
``diagnose --families`` are both accepted wherever an effect with a place is named, read by
one function."""

from __future__ import annotations

import pytest

from stiffness.elastic.effects import LIBRARY
from stiffness.elastic.effects.base import effect_place
from stiffness.errors import StiffnessError
from stiffness.planning.design import parse_separate
from stiffness.planning.simulate import parse_effect


@pytest.mark.parametrize("text, name, where", [
    ("backlash", "backlash", None),
    ("backlash:", "backlash", None),
    (" backlash : joint2 ", "backlash", "joint2"),
    ("backlash(joint2)", "backlash", "joint2"),
    ("link_compliance:a->b", "link_compliance", "a->b"),
    ("link_compliance(a->b)", "link_compliance", "a->b"),
    ("backlash:j(1)", "backlash", "j(1)"),      # a URDF joint with brackets in its name
    ("backlash(j(1))", "backlash", "j(1)"),
    ("backlash:a:b", "backlash", "a:b"),        # and with a colon
    ("backlash(a:b)", "backlash", "a:b"),
])
def test_both_spellings_name_the_same_place(text, name, where):
    assert effect_place(text, "--x") == (name, where)


@pytest.mark.parametrize("text, words", [
    ("backlash(joint2", "closing bracket at the end"),
    ("backlash(joint2)x", "closing bracket at the end"),
    ("backlash()", "closing bracket"),
    ("backlash:(joint2)", r"reads two ways: write backlash\(joint2\) for the place joint2, or "
                          r"backlash\(\(joint2\)\) for a place named \(joint2\)"),
])
def test_a_place_that_is_not_closed_or_reads_two_ways_is_refused(text, words):
    with pytest.raises(StiffnessError, match=words):
        effect_place(text, "--x")


def test_no_effect_name_holds_a_place_mark():
    """What lets the name end at the first ':' or '(' (any text after is the place)."""
    assert all(name.isidentifier() for name in LIBRARY)


def test_simulate_and_design_take_the_label_spelling():
    """``simulate --effect NAME(WHERE)=V`` and ``design --separate NAME(WHERE),...`` (they
    said 'unknown effect 'backlash(joint2)'')."""
    assert parse_effect("backlash(joint2)=0.003") == parse_effect("backlash:joint2=0.003")
    assert parse_effect("link_compliance(joint2->elbow)=2e6").where == "joint2->elbow"
    assert parse_separate("backlash(joint2),link_compliance(joint2->elbow)") == (
        ("backlash", "joint2"), ("link_compliance", "joint2->elbow"))
    assert parse_separate("backlash:joint2,link_compliance(joint2->elbow)") == (
        ("backlash", "joint2"), ("link_compliance", "joint2->elbow"))
