"""A vehicle's life (nrtraffic.lifecycle): every legal transition is walked, every other refused,
and the views keep the order of arrival that first-come-first-served relies on."""

import itertools

import pytest

from nrtraffic.lifecycle import (CLEARS_MARK, KEEP_PLACE, LABEL, TRANSITIONS, IllegalTransition, Lifecycle, State,
                                 VehicleRecord)

S = State


def _reach(target: State) -> list[State]:
    """A path of legal transitions from WAITING to ``target`` (breadth first)."""
    paths = {S.WAITING: [S.WAITING]}
    frontier = [S.WAITING]
    while frontier:
        nxt = []
        for s in frontier:
            for t in TRANSITIONS[s]:
                if t not in paths:
                    paths[t] = paths[s] + [t]
                    nxt.append(t)
        frontier = nxt
    return paths[target]


def _life_in(state: State, vid="v") -> Lifecycle:
    life = Lifecycle({vid: VehicleRecord(vid, "N_in", 0.0)})
    life.add(vid, "C")
    for s in _reach(state)[1:]:
        life.move(vid, s)
    assert life.state(vid) is state
    return life


def test_every_state_is_reachable_and_every_live_state_has_a_way_out():
    for s in State:
        assert _reach(s)[-1] is s
    # only the ends of a life have no transition out
    assert {s for s, out in TRANSITIONS.items() if not out} == {S.LOST, S.GONE}


@pytest.mark.parametrize("src, dst", sorted(itertools.product(State, State), key=lambda p: (p[0].value, p[1].value)))
def test_each_transition_is_taken_or_refused(src, dst):
    life = _life_in(src)
    if dst in TRANSITIONS[src]:
        life.move("v", dst)
        assert life.state("v") is dst
        assert life.members(dst) == ["v"]
        assert all("v" not in life.members(s) for s in State if s is not dst)
        if dst is not S.GONE:  # the record's label follows the state; gone keeps the last one
            assert life.records["v"].status == LABEL.get(dst, dst.value)
    else:
        with pytest.raises(IllegalTransition):
            life.move("v", dst)
        assert life.state("v") is src  # a refused move changes nothing


def test_unknown_vehicle_and_double_insertion_are_refused():
    life = Lifecycle({})
    with pytest.raises(IllegalTransition):
        life.move("x", S.APPROACHING)
    life.add("x", "C")
    with pytest.raises(IllegalTransition):
        life.add("x", "C")


def test_views_keep_the_order_of_arrival():
    """A held vehicle keeps its place among the approaching ones; a batched one joins the batch
    last; a junction's view holds only its own vehicles."""
    recs = {v: VehicleRecord(v, "N_in", 0.0) for v in "abcd"}
    life = Lifecycle(recs)
    for v, j in zip("abcd", "CCDC"):
        life.add(v, j)
        life.move(v, S.APPROACHING)
    life.move("b", S.HELD)
    assert life.members(S.APPROACHING, S.HELD) == ["a", "b", "c", "d"]
    assert life.members(S.APPROACHING, S.HELD, junction="C") == ["a", "b", "d"]
    life.move("d", S.BATCHED)
    life.move("a", S.BATCHED)
    life.move("d", S.HELD)
    assert life.members(S.BATCHED, S.HELD) == ["b", "d", "a"]
    # the order of KEEP_PLACE transitions is what the original lists kept
    assert (S.APPROACHING, S.BATCHED) not in KEEP_PLACE and (S.APPROACHING, S.HELD) in KEEP_PLACE


def test_a_mark_at_the_stop_line_ends_when_the_crossing_is_reserved_or_the_vehicle_leaves():
    recs = {v: VehicleRecord(v, "N_in", 0.0) for v in "hc"}
    life = Lifecycle(recs)
    life.add("h", "C")
    life.move("h", S.SUMO)
    life.move("h", S.HUMAN)
    life.wait_at_line("h", "N_in_0")
    life.add("c", "C")
    life.move("c", S.APPROACHING)
    life.wait_at_line("c", "N_in_0")
    assert set(life.waiting_at_line("N_in_0")) == {"h", "c"}
    with pytest.raises(IllegalTransition):
        life.wait_at_line("c", "N_in_0")
    life.move("h", S.RESERVED)
    life.move("c", S.HELD)  # still waiting: held is not in CLEARS_MARK
    assert list(life.waiting_at_line("N_in_0")) == ["c"]
    life.move("c", S.STARTING)
    assert not life.waiting_at_line("N_in_0")
    assert S.HELD not in CLEARS_MARK and S.STARTING in CLEARS_MARK
