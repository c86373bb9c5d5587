"""The run's demand: arrivals drawn from its random generator, the departures of every vehicle,
and the demand of a window (no SUMO run; :meth:`Demand.write` writes SUMO's route file)."""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path

import numpy as np

from nrtraffic.scenario import TURNS, top_speed


def shifted_exponential_arrivals(rng: np.random.Generator, begin_s: float, end_s: float, mean_headway_s: float,
                                 min_headway_s: float, max_vehicles: int = 0) -> np.ndarray:
    """Departure times [s] in ``[begin_s, end_s]``: the first after one headway, then headways
    ``min_headway_s + Exp(mean_headway_s - min_headway_s)`` (mean ``mean_headway_s``).

    ``max_vehicles`` > 0 caps the count; ``end_s`` may be ``inf`` when it does.
    """
    if max_vehicles <= 0 and not np.isfinite(end_s):
        raise ValueError("arrivals need a finite end time or a maximum number of vehicles")
    out = []
    t = begin_s
    scale = mean_headway_s - min_headway_s
    while True:
        t += min_headway_s + rng.exponential(scale)
        if t > end_s or (max_vehicles > 0 and len(out) >= max_vehicles):
            break
        out.append(t)
    return np.array(out)


BACKGROUND = "background"  # the route names of a route file's vehicles that cross no controlled junction
SHARE_STREAM = 0x6875_6D61_6E  # the run seed's stream that draws which vehicles are controlled ("human")
ROUTE_STREAM = 0x726F_757465  # the run seed's stream that draws a vehicle's turns after its first junction ("route")


class Demand:
    """The run's departures and the demand of a window, from the scenario and the junctions'
    :class:`~nrtraffic.junction.Layout` (no SUMO run).

    :meth:`departures` are ``(vehicle_id, route, depart_s, depart_speed_mps, depart_pos_m, type,
    depart_lane)`` in order of departure; ``route`` is a turning movement, or on a corridor a trip
    through several junctions (:attr:`itineraries`); ``type`` is "auto" or "human"; ``depart_lane``
    SUMO's departLane ("best" unless a route file gives one).
    """

    def __init__(self, sc, layout, seed: int, duration_s: float):
        self.sc, self.layout, self.seed, self.duration = sc, layout, int(seed), float(duration_s)
        self.itineraries: dict[str, tuple[str, ...]] = {}
        self.file_routes: dict[str, tuple[str, ...]] = {}  # a route file's route -> its edges, whole
        # a route file's vehicles that cross no controlled junction (as departures; "background~k" routes):
        # written for SUMO to drive, left out of the run's demand and figures
        self.background: list[tuple] = []
        # a route file's vehicles sent in slower than the entry speed because the first edge's speed
        # limit, or a link where they give way just after their start, allows no more (its departSpeed
        # not a number): SUMO's driver takes them to their control zone, and their free-flow speed is the
        # entry speed
        self.paced: set[str] = set()
        self.background_routes: dict[str, tuple[str, ...]] = {}
        self.notes: list[str] = []  # what the run does differently from the demand as given (summary warnings)
        self._departures: list[tuple] | None = None
        if sc.general.sumocfg:
            from nrtraffic.scenario import sumocfg_unused

            unused = sumocfg_unused(sc.base_dir / sc.general.sumocfg)
            if unused:
                self.notes.append(f"scenario.sumocfg: the run takes its network, route files, begin and end; its "
                                  f"{', '.join(unused)} are not used (SUMO's settings are the [sumo] keys and "
                                  "sumo.extra_args)")

    @classmethod
    def of(cls, sc, seed: int | None = None, duration_s: float | None = None, network=None) -> "Demand":
        """The demand of a run of ``sc`` (its seed and duration unless given), on its network or
        ``network``: reads the network file, SUMO is not started."""
        from nrtraffic.junction import Layout

        return cls(sc, Layout(sc, network if network is not None else sc.network_path),
                   sc.general.seed if seed is None else seed,
                   sc.general.duration_s if duration_s is None else duration_s)

    @property
    def movement_table(self):
        return self.layout.movement_table

    def departures(self) -> list[tuple]:
        """Departures from the run's random generator (drawn once): per approach, shifted-
        exponential headways at the approach's rate (times the scale of each ``[[demand.intervals]]``
        period); each vehicle draws its movement from the approach's turning movement counts
        (``[[demand.flows]]``) or the global turning shares. ``type`` is "auto" or "human": in order
        of departure, each vehicle draws a uniform number from its own stream of the seed (the
        arrivals do not change with the share) and is a human driver when it is at least
        ``demand.controlled_share``; a vehicle controlled at one share is controlled at every higher
        one. ``[[vehicles]]`` keep their ``controlled``."""
        if self._departures is None:
            self._departures = self._draw()
        return self._departures

    def _draw(self) -> list[tuple]:
        d = self.sc.demand
        rng = np.random.default_rng(self.seed)
        veh = []
        if d.sumo_routes:
            veh = self._file_departures(rng)
        rates = self.approach_rates() if not d.sumo_routes else {}
        if rates:
            end = d.end_s if d.end_s > 0 else (self.duration if self.duration > 0 else math.inf)
            if d.max_vehicles == 0 and not math.isfinite(end):
                raise ValueError("random demand needs an end: demand.max_vehicles, demand.end_s, or a run length "
                                 "(scenario.duration_s, or --duration other than 0)")
            for appr, (rate, names, share) in rates.items():
                if rate <= 0 or appr not in self.layout.entry_approaches:  # (a corridor's inner approach: shares only)
                    continue
                times = self._arrival_times(rng, rate, end)
                picks = rng.choice(len(names), size=len(times), p=share / share.sum())
                veh += [(f"{appr}.{k}", names[j], float(t), d.entry_speed_mps, -1.0)
                        for k, (t, j) in enumerate(zip(times, picks))]
        for v in self.sc.vehicles:
            mv = v.approach
            if mv not in self.movement_table:
                raise ValueError(f"vehicle {v.id}: {mv!r} is not a movement ({', '.join(self.movement_table)})")
            veh.append((v.id, mv, v.depart_s, v.depart_speed_mps, v.depart_pos_m))
        twice = [i for i, n in Counter(v[0] for v in veh).items() if n > 1]
        if twice:
            listed = {v.id for v in self.sc.vehicles}
            if twice[0] in listed:
                raise ValueError(f"vehicle id {twice[0]!r} is given twice ([[vehicles]] and the generated or file "
                                 "demand name vehicles <approach>.<k> and by the file's ids): give the [[vehicles]] "
                                 "another id")
            raise ValueError(f"vehicle id {twice[0]!r} is given twice: by demand.sumo_routes, and by the copy that "
                             f"demand.scale = {self.sc.demand.scale:g} makes of another of its vehicles (named "
                             "<id>#<k>): rename that vehicle in the file")
        veh.sort(key=lambda v: v[2])
        if self.layout.next_junction:
            veh = self._extend_routes(veh, rates)
        u = np.random.default_rng([self.seed, SHARE_STREAM]).random(len(veh))
        share = d.controlled_share
        listed = {v.id for v in self.sc.vehicles}
        return [(*v[:5], "human" if (x >= share and v[0] not in listed) else "auto", v[5] if len(v) > 5 else "best")
                for v, x in zip(veh, u)]

    def _file_departures(self, rng) -> list[tuple]:
        """``demand.sumo_routes``: the files' departures (trips routed by duarouter) from
        ``scenario.begin_s`` on, measured from it, each on its whole route, named by the movements
        it takes joined with "+" and "~k" (the k-th route with those crossings); :attr:`itineraries`
        and :attr:`file_routes`. With ``demand.scale``, each vehicle is there ``int(scale)``
        times and once more with the chance of the fraction (the copies named ``<id>#<k>``; SUMO's
        ``--scale``); with ``demand.depart_offset_s``, each departure is later by a uniform random
        time up to it; both drawn from the run's seed."""
        from nrtraffic.sumo.adapter import VehicleType
        from nrtraffic.sumo.demandfile import merged, read_sumo_demand, routed
        from nrtraffic.sumo.network import read_net

        d = self.sc.demand
        t0 = self.sc.general.begin_s  # the file's times are SUMO's clock: the run starts at t0
        end = d.end_s if d.end_s > 0 else (self.duration if self.duration > 0 else math.inf)
        by_edges = {(r[0], r[1]): name for name, (_, _, r) in self.movement_table.items()}
        net = read_net(self.sc.network_path)
        files = d.route_files(self.sc.base_dir)
        safe = (self.sc.vehicle.params().length, VehicleType.decel_mps2, self.sc.sumo.step_length_s)
        read = read_sumo_demand(routed(merged(files), self.sc.network_path), by_edges, rng, t0 + end, d.entry_speed_mps,
                                net=net, source=", ".join(f.name for f in files), notes=self.notes, safe_start=safe)
        named: dict[tuple, str] = {}
        variants: dict[tuple, int] = {}  # crossings -> routes named for them so far
        veh = []
        classes: dict[str, int] = {}
        if d.scale != 1.0:  # SUMO's --scale: each vehicle int(scale) times, and once more with the rest's chance
            whole, rest = divmod(d.scale, 1.0)
            copies = int(whole) + (rng.random(len(read)) < rest)
            read = [(v[0] if k == 0 else f"{v[0]}#{k}", *v[1:]) for v, n in zip(read, copies.tolist())
                    for k in range(n)]
        offsets = rng.uniform(0.0, d.depart_offset_s, len(read)) if d.depart_offset_s > 0 else np.zeros(len(read))
        for (vid, legs, t, v0, pos, edges, lane, vclass, slowed), extra in zip(read, offsets.tolist()):
            t += extra - t0  # (SUMO's --random-depart-offset, drawn from the run's seed)
            if t < -1e-9:  # (before the run's start: SUMO does not insert it either)
                continue
            if slowed and legs:
                self.paced.add(vid)
            if not legs:  # (crosses no controlled junction: SUMO drives it, the figures leave it out)
                key = named.get(((), edges))
                if key is None:
                    key = named[((), edges)] = f"{BACKGROUND}~{len(self.background_routes)}"
                    self.background_routes[key] = edges
                self.background.append((vid, key, t, v0, pos, "auto", lane))
                continue
            key = named.get((legs, edges))
            if key is None:
                k = variants[legs] = variants.get(legs, -1) + 1
                key = f"{'+'.join(legs)}~{k}"  # (never a movement's own name: [[vehicles]] keep theirs)
                named[(legs, edges)] = key
                self.itineraries[key] = legs
                self.file_routes[key] = edges
            classes[vclass] = classes.get(vclass, 0) + 1
            veh.append((vid, key, t, v0, pos, lane))
        others = {k: n for k, n in classes.items() if k != "passenger"}
        if veh:
            among = ", ".join(f"{n} of vClass {k}" for k, n in sorted(others.items()))
            self.notes.append(f"demand.sumo_routes: its {len(veh)} vehicles drive as nrtraffic's car (the file's "
                              "vTypes are not used)" + (f", {among} among them" if others else ""))
        if self.background:
            self.notes.append(f"demand.sumo_routes: {len(self.background)} of its vehicles cross no controlled "
                              "junction: SUMO drives them on their routes as nrtraffic's car, and the run's figures "
                              "leave them out")
        return veh

    def _arrival_times(self, rng, rate: float, end: float) -> np.ndarray:
        """One approach's departure times [s] at ``rate`` [veh/h], scaled by the intervals."""
        d = self.sc.demand
        if not d.intervals:
            headway = 3600.0 / rate if d.flows else d.headway_s  # (as given: the same draws)
            return shifted_exponential_arrivals(rng, d.begin_s, end, headway, d.min_headway_s, d.max_vehicles)
        pieces, last = [], d.begin_s
        cuts = d.breakpoints(d.begin_s, end)
        for b, e in zip(cuts, cuts[1:]):
            scale = d.scale_at(b)
            if scale > 0:
                left = d.max_vehicles - sum(len(x) for x in pieces) if d.max_vehicles else 0
                if d.max_vehicles and left <= 0:
                    break
                got = shifted_exponential_arrivals(rng, max(b, last), e, 3600.0 / (rate * scale), d.min_headway_s,
                                                   left)
                pieces.append(got)
                last = got[-1] if len(got) else last
        return np.concatenate(pieces) if pieces else np.zeros(0)

    def _extend_routes(self, veh: list[tuple], rates: dict) -> list[tuple]:
        """A corridor: each departure's route continues through every controlled junction its last
        movement leads into, with a turn drawn there (its own stream of the seed, in order of
        departure) from that approach's shares (``[[demand.flows]]`` of the approach, as turning
        movement counts, else the global turning shares). The route of a trip through several
        junctions is named by its movements joined with "+" (:attr:`itineraries`)."""
        rng = np.random.default_rng([self.seed, ROUTE_STREAM])
        shares = {}
        for appr in {a for a, _, _ in self.movement_table.values()}:
            if appr in rates:
                _, names, share = rates[appr]
            else:
                names = [n for n, (a, _, _) in self.movement_table.items() if a == appr]
                share = self.default_shares(names)
            if share.sum() <= 0:
                share = np.ones(len(names))
            shares[appr] = (names, share / share.sum())
        out = []
        for vid, first, *rest in veh:
            if first in self.file_routes:  # (a route file's vehicle: its crossings are its route's)
                out.append((vid, first, *rest))
                continue
            legs = [first]
            while len(legs) <= len(self.layout.junctions):
                edge_out = self.movement_table[legs[-1]][2][-1]
                if edge_out not in self.layout.next_junction:
                    break
                names, p = shares[edge_out]
                legs.append(names[int(rng.choice(len(names), p=p))])
            key = "+".join(legs)
            self.itineraries[key] = tuple(legs)
            out.append((vid, key, *rest))
        return out

    def route_edges(self, route: str) -> tuple[str, ...]:
        """The edges of a demand route: a turning movement's, or a corridor trip's (:attr:`itineraries`),
        from the start of the road that feeds its first approach (``Layout.feeders``)."""
        if route in self.file_routes:
            return self.file_routes[route]
        if route in self.background_routes:
            return self.background_routes[route]
        legs = self.legs(route)
        edges = [*self.layout.feeders.get(legs[0], ()), *self.movement_table[legs[0]][2]]
        for leg in legs[1:]:
            edges += list(self.movement_table[leg][2][1:])
        return tuple(edges)

    def legs(self, route: str) -> tuple[str, ...]:
        """The turning movements a demand route takes, in order (one, off a corridor)."""
        return self.itineraries.get(route, (route,))

    def used_movements(self) -> set[str]:
        """The turning movements some departure takes."""
        return {leg for _, route, *_ in self.departures() for leg in self.legs(route)}

    def first_approach(self, route: str) -> str:
        """The approach of the first junction a demand route enters."""
        return self.movement_table[self.legs(route)[0]][0]

    def _uncontrolled_hint(self, edges: list[str]) -> str:
        """Where ``edges`` lead into junctions of the network that the scenario does not control,
        the fix: control them, or drop the flows ('' when no edge does)."""
        from nrtraffic.sumo.network import read_net

        net = read_net(self.sc.network_path)
        nodes = sorted({net.getEdge(e).getToNode().getID() for e in edges if net.hasEdge(e)}
                       - set(self.layout.junctions))
        if not nodes:
            return ""
        listed = " ".join(f'[[junctions]] id = "{n}"' for n in nodes)
        return (f"; they lead into {', '.join(nodes)}, which the scenario does not control: add {listed}, "
                f"or remove their [[demand.flows]]")

    def approach_rates(self) -> dict[str, tuple[float, list[str], np.ndarray]]:
        """Per approach: its arrival rate [veh/h] (before the intervals' scale), its movements and
        their shares of it; empty without random demand. Raises ValueError naming the key when
        ``[[demand.flows]]`` names an approach or a turn the junction does not have."""
        d = self.sc.demand
        approaches: dict[str, list[str]] = {}
        for name, (appr, _, _) in self.movement_table.items():
            approaches.setdefault(appr, []).append(name)
        out = {}
        if d.flows:
            known = {f.approach for f in d.flows}
            unknown = sorted(known - set(approaches))
            if unknown:
                raise ValueError(f"demand.flows: {', '.join(unknown)} is not an approach of the junction "
                                 f"({', '.join(approaches)}){self._uncontrolled_hint(unknown)}")
            for f in d.flows:
                names = approaches[f.approach]
                turns = {self.movement_table[n][1]: n for n in names}
                for key in TURNS:
                    turn = "uturn" if key == "u_turn" else key
                    if getattr(f, key) > 0 and turn not in turns:
                        raise ValueError(f"demand.flows.{f.approach}.{key}: the approach has no such movement "
                                         f"(it has {', '.join(sorted(turns))})")
                kinds = [self.movement_table[n][1] for n in names]  # (two roads of one turn share its count)
                share = np.array([getattr(f, "u_turn" if k == "uturn" else k, 0.0) / kinds.count(k) for k in kinds],
                                 dtype=float)
                out[f.approach] = (f.total_veh_h, names, share)
            return out
        if d.headway_s <= 0:
            return {}
        for appr, names in approaches.items():
            out[appr] = (3600.0 / d.headway_s, names, self.default_shares(names))
        return out

    def default_shares(self, names: list[str]) -> np.ndarray:
        """The global turning shares (``demand.turn_left``, ``turn_right``, the rest straight, no
        U-turn) of turning movements ``names`` of one approach; equal shares where they give none."""
        d = self.sc.demand
        kinds = [self.movement_table[n][1] for n in names]  # (two roads of one turn share it)
        by_turn = {"left": d.turn_left, "right": d.turn_right, "uturn": 0.0}
        share = np.array([by_turn.get(k, 1.0 - d.turn_left - d.turn_right) / kinds.count(k) for k in kinds])
        return share if share.sum() > 0 else np.array([0.0 if k == "uturn" else 1.0 for k in kinds])

    def demand_veh_h(self, begin: float, end: float, approach: str | None = None) -> float:
        """Mean demand into the junctions (or one approach) over ``[begin, end]`` [veh/h]: every
        entry approach's rate times the intervals' scale, averaged over the window (not the sampled
        arrivals); with ``demand.sumo_routes``, the file's departures in the window."""
        if self.sc.demand.sumo_routes:
            times = [t for _, route, t, *_ in self.departures()
                     if begin <= t <= end and (approach is None or self.first_approach(route) == approach)]
            return len(times) / (end - begin) * 3600.0 if end > begin else 0.0
        if approach is not None and approach not in self.layout.entry_approaches:
            return math.nan  # a corridor's inner approach: fed by the junction upstream, not by demand
        rates = {a: r for a, r in self.approach_rates().items() if a in self.layout.entry_approaches}
        if approach is not None:
            rates = {a: r for a, r in rates.items() if a == approach}
        total = sum(r for r, _, _ in rates.values())
        d = self.sc.demand
        lo, hi = max(begin, d.begin_s), min(end, d.end_s if d.end_s > 0 else end)
        if end <= begin or hi <= lo:
            return 0.0
        cuts = d.breakpoints(lo, hi)
        return total * sum((b - a) * d.scale_at(a) for a, b in zip(cuts, cuts[1:])) / (end - begin)

    def write(self, path: Path, params, human=None) -> list[tuple]:
        """The departures as a SUMO route file in nrtraffic's vehicle type (``params``: the
        vehicle's :class:`~nrtraffic.vehicle.params.VehicleParams`; ``human``: the ``[human]``
        section, for a human driver's type); returns them."""
        from nrtraffic.sumo.adapter import VehicleType, write_routes

        demand = self.departures()
        v_max = top_speed(self.sc)
        types = [VehicleType(length_m=params.length, width_m=params.width, max_speed_mps=v_max)]
        if any(v[5] == "human" for v in demand):
            h = self.sc.human
            types.append(VehicleType("human", params.length, params.width, h.min_gap_m, h.accel_mps2, h.decel_mps2,
                                     v_max, h.sigma, h.tau_s, h.speed_dev, h.car_follow_model))
        routes = {k: self.route_edges(k) for k in [*self.movement_table, *self.itineraries]}
        vehicles = demand
        if self.background:  # (the route file in order of departure, as SUMO reads it)
            routes.update(self.background_routes)
            vehicles = sorted([*demand, *self.background], key=lambda v: v[2])
        write_routes(path, types, routes, vehicles, t0_s=self.sc.general.begin_s)
        return demand
