"""A vehicle's life in a run: its record, its states and the legal transitions between them.

Every vehicle of the demand passes through these states (one record per crossing of a junction; on
a corridor a vehicle released by one junction starts a new record, and a new life, for the next).
The legal transitions (:data:`TRANSITIONS`):

    waiting      -> approaching | sumo
    approaching  -> batched | held | starting | controlled
    batched      -> held | starting | controlled
    held         -> starting | controlled
    starting     -> controlled | lost
    controlled   -> released | starting (late: its start reserved again) | lost
    released     -> approaching (its next junction) | gone
    sumo         -> sumo (its next junction) | human | gone
    human        -> reserved | gone
    reserved     -> crossing | gone
    crossing     -> crossed | human (its next junction) | gone
    crossed      -> gone

- ``approaching``: SUMO drives it towards (and into) its control zone at its entry speed;
- ``batched``: in the control zone, waiting for its junction's batch (``policy = "batch"``);
- ``held``: no merge time meets the bounds; SUMO drives it on to its stop line and it is tried
  again on the way;
- ``starting``: standing at its stop line (or in a standing queue before it), its start from rest
  reserved;
- ``controlled``: the kernel drives it; one held up before its merging zone so long that it would
  enter it late stops before it, and its start from rest is reserved again
  (:mod:`nrtraffic.junction.late`);
- ``released``: past the merging zone, handed back to SUMO, still read as a possible leader;
- ``sumo``: SUMO drives it throughout (a baseline, a scripted vehicle);
- ``human`` -> ``reserved`` -> ``crossing`` -> ``crossed``: a human driver on its way to the stop
  line, standing there with its crossing reserved, crossing, and past the merging zone;
- ``lost``: SUMO no longer lists a vehicle under control; ``gone``: no longer read (it left the
  network, or a released vehicle is far down its exit road).

:class:`Lifecycle` owns the state of every vehicle; each list of "who is where" that the run reads
(:meth:`Lifecycle.members`) is a view of it, in the order the vehicles entered the queue they are in.
An illegal transition raises :class:`IllegalTransition`. A vehicle whose crossing is not reserved
yet and that stands or will stand at its stop line (a human driver, a held vehicle, or a controlled
vehicle queued behind one) is also marked on its entry lane (:meth:`Lifecycle.wait_at_line`): the vehicles behind
it on that lane wait for it.
"""

from __future__ import annotations

import enum
import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from nrtraffic.control import batch as kb


class State(enum.Enum):
    WAITING = "waiting"
    APPROACHING = "approaching"
    BATCHED = "batched"
    HELD = "held"
    STARTING = "starting"
    CONTROLLED = "controlled"
    RELEASED = "released"
    LOST = "lost"
    SUMO = "sumo"
    HUMAN = "human"
    RESERVED = "reserved"
    CROSSING = "crossing"
    CROSSED = "crossed"
    GONE = "gone"


S = State
# the legal transitions; a vehicle starts in WAITING when SUMO inserts it
TRANSITIONS: dict[State, frozenset[State]] = {
    S.WAITING: frozenset({S.APPROACHING, S.SUMO}),
    S.APPROACHING: frozenset({S.BATCHED, S.HELD, S.STARTING, S.CONTROLLED}),
    S.BATCHED: frozenset({S.HELD, S.STARTING, S.CONTROLLED}),
    S.HELD: frozenset({S.STARTING, S.CONTROLLED}),
    S.STARTING: frozenset({S.CONTROLLED, S.LOST}),
    S.CONTROLLED: frozenset({S.RELEASED, S.STARTING, S.LOST}),
    S.RELEASED: frozenset({S.APPROACHING, S.GONE}),  # approaching: the next junction of its trip
    S.LOST: frozenset(),
    S.SUMO: frozenset({S.SUMO, S.HUMAN, S.GONE}),  # sumo -> sumo: on to the next junction of its trip
    S.HUMAN: frozenset({S.RESERVED, S.GONE}),
    S.RESERVED: frozenset({S.CROSSING, S.GONE}),
    S.CROSSING: frozenset({S.CROSSED, S.HUMAN, S.GONE}),  # human: the next junction of its trip
    S.CROSSED: frozenset({S.GONE}),
    S.GONE: frozenset(),
}
# transitions in which a vehicle keeps its place in the queue it is in (the others put it last)
KEEP_PLACE = frozenset({(S.APPROACHING, S.HELD), (S.BATCHED, S.HELD), (S.SUMO, S.HUMAN), (S.SUMO, S.SUMO),
                        (S.HUMAN, S.RESERVED), (S.RESERVED, S.CROSSING), (S.CROSSING, S.CROSSED),
                        (S.CROSSING, S.HUMAN)})
# the status vehicles.csv gives a vehicle in a state: a batched vehicle is still "approaching", a
# human driver past the zone "crossing", and a vehicle no longer read keeps the status it had
LABEL = {S.BATCHED: "approaching", S.CROSSED: "crossing"}
# states a vehicle's mark on its lane's stop line ends in: its crossing is reserved or under control,
# or it left
CLEARS_MARK = frozenset({S.RESERVED, S.STARTING, S.CONTROLLED, S.GONE})
# SUMO drives the vehicle, and the run measures its zone crossings (:mod:`nrtraffic.measure`)
SUMO_DRIVEN = (S.SUMO, S.HUMAN, S.RESERVED, S.CROSSING, S.CROSSED)
HUMAN_DRIVERS = (S.HUMAN, S.RESERVED, S.CROSSING)  # human drivers until they leave the merging zone


class IllegalTransition(RuntimeError):
    """A vehicle was moved to a state that cannot follow the one it is in."""


@dataclass
class VehicleRecord:
    """One vehicle's crossing of one junction: who it is, what it was planned and what it did.
    Times [s], positions along its path [m], speeds [m/s]. ``status`` is the label of its state
    (:data:`LABEL`), kept by :class:`Lifecycle`."""

    vehicle_id: str
    approach: str
    t_depart: float
    movement: str = ""  # its lane-level movement (a key of the run's paths), from the lane SUMO gives it
    route: str = ""  # its turning movement (the demand's route name)
    lane: str = ""  # its entry lane: the coordinator's lane key
    lane_kept: bool = True  # SUMO keeps it on its lane (False: it changes lanes for its route until its zone)
    junction: str = ""  # the junction it crosses (a record is one crossing; a corridor trip has several)
    legs: tuple = ()  # the turning movements of its trip, one per junction, in order
    leg: int = 0  # which of them this record is
    v_free: float = math.nan  # its free-flow speed: the speed it was sent in with [m/s]
    controlled: bool = True
    driver: str = "automated"  # or "human" (demand.controlled_share): what kind of vehicle it is
    heading_offset: float = 0.0
    speed_profile: tuple = ()
    status: str = "waiting"
    t_enter: float = math.nan
    v_enter: float = math.nan
    s_enter: float = math.nan
    t_merge_planned: float = math.nan
    v_merge_planned: float = math.nan
    t_merge_actual: float = math.nan
    t_exit: float = math.nan
    predecessor: str | None = None
    relation: str = ""
    binding: str = ""
    profile_kind: str = ""
    plan_intrusion: float = math.nan
    acc: np.ndarray = field(default_factory=lambda: kb.new_acc(1)[0])
    min_gap: float = math.inf
    s_last: float = math.nan
    t_held: float = 0.0  # time held at the control-zone entry for want of a feasible schedule [s]
    hindered: bool = False  # its scheduling waited for a human driver ahead on its lane
    t_release: float = math.nan  # a human driver: when its reserved crossing starts [s]
    depart_delay: float = 0.0  # SUMO's wait to insert it past its desired departure (a backed-up lane) [s]
    t_arrive: float = math.nan  # when its centre of gravity crossed the control-zone entry [s] ...
    s_arrive: float = math.nan  # ... and where on its path it was then [m] (delay is counted from there)
    look_after: float = -math.inf  # before its zone entry: the earliest time it can reach it [s]
    replans: int = 0  # how often its plan was made again (late: junction.late; giving way: junction.yielding)


class Lifecycle:
    """The state of every vehicle of a run, and the views of it.

    ``records`` is the run's vehicle id -> current :class:`VehicleRecord`; :meth:`move` keeps each
    record's ``status`` label. The views list vehicles in the order they entered the queue they are
    in: the order of arrival that first-come-first-served rules rely on.
    """

    def __init__(self, records: dict[str, VehicleRecord]):
        self.records = records
        self._state: dict[str, State] = {}
        self._junction: dict[str, str] = {}
        self._members: dict[State, dict[str, int]] = {s: {} for s in State}  # state -> vehicle -> place
        self._place = itertools.count()
        self._marks: dict[str, dict[str, None]] = {}  # entry lane -> vehicles waiting at its stop line
        self._marked: dict[str, str] = {}  # vehicle -> the lane it is marked on

    def add(self, vid: str, junction: str) -> None:
        """A vehicle SUMO has just inserted, in ``waiting``, at ``junction``."""
        if vid in self._state and self._state[vid] is not S.GONE:
            raise IllegalTransition(f"vehicle {vid} is already in the run ({self._state[vid].value})")
        self._set(vid, S.WAITING, next(self._place))
        self._junction[vid] = junction

    def move(self, vid: str, to: State, junction: str | None = None) -> None:
        """Move vehicle ``vid`` to state ``to`` (at ``junction`` when it changes: the next junction
        of its trip). Raises :class:`IllegalTransition` where ``to`` cannot follow its state."""
        now = self._state.get(vid)
        if now is None or to not in TRANSITIONS[now]:
            raise IllegalTransition(f"vehicle {vid}: {now.value if now else 'unknown'} -> {to.value} is not a "
                                    f"transition of its life")
        place = self._members[now].pop(vid)
        self._set(vid, to, place if (now, to) in KEEP_PLACE else next(self._place))
        if junction is not None:
            self._junction[vid] = junction
        if to in CLEARS_MARK and vid in self._marked:
            del self._marks[self._marked.pop(vid)][vid]

    def _set(self, vid: str, state: State, place: int) -> None:
        self._state[vid] = state
        d = self._members[state]
        if d and place < next(reversed(d.values())):  # (a kept place: the state's queue stays in order)
            d[vid] = place
            self._members[state] = dict(sorted(d.items(), key=lambda kv: kv[1]))
        else:
            d[vid] = place
        if state is not S.GONE and vid in self.records:
            self.records[vid].status = LABEL.get(state, state.value)

    def state(self, vid: str) -> State | None:
        return self._state.get(vid)

    def members(self, *states: State, junction: str | None = None) -> list[str]:
        """The vehicles in any of ``states`` (at ``junction``, if given), in the order they entered
        their queue."""
        m = self._members
        if len(states) == 1:  # each state's queue is kept in order of places
            out = list(m[states[0]])
        else:
            queues = [m[s] for s in states if m[s]]
            if len(queues) <= 1:
                out = list(queues[0]) if queues else []
            else:
                places = {v: p for d in queues for v, p in d.items()}
                out = sorted(places, key=places.__getitem__)
        if junction is not None:
            out = [v for v in out if self._junction[v] == junction]
        return out

    def by_junction(self, *states: State) -> dict[str, list[str]]:
        """:meth:`members` of ``states`` at every junction at once (junction -> its vehicles, in
        order; junctions with none left out): one pass, however many junctions there are."""
        out: dict[str, list[str]] = {}
        for v in self.members(*states):
            out.setdefault(self._junction[v], []).append(v)
        return out

    def count(self, state: State) -> int:
        return len(self._members[state])

    # ------------------------------------------------------------ marks on the stop lines
    def wait_at_line(self, vid: str, lane: str) -> None:
        """Mark ``vid`` as waiting, crossing not reserved, at the stop line of entry lane ``lane``
        until it moves to a state of :data:`CLEARS_MARK`."""
        if vid in self._marked:
            raise IllegalTransition(f"vehicle {vid} already waits at the stop line of {self._marked[vid]}")
        self._marks.setdefault(lane, {})[vid] = None
        self._marked[vid] = lane

    def waiting_at_line(self, lane: str) -> dict[str, None]:
        """The vehicles marked on ``lane`` (read only)."""
        return self._marks.get(lane, {})
