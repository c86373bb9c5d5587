"""A route file's vehicles that cross no controlled junction: background traffic
(:attr:`nrtraffic.demand.Demand.background`). SUMO drives them, and the run's figures leave them
out. Those whose routes never touch a road of a movement's path are never read from SUMO; the
others are read (a leader, a queue on an exit road) until they are past the last such road of
their route, so that a step's reading grows with the traffic near the junctions, not with the
city's."""

from __future__ import annotations

from nrtraffic.sumo.network import edge_of


class Background:
    """The background vehicles of a run (``demand``) on its paths (``st.paths``, built): sets
    ``st.sumo.unread``; :meth:`departed` and :meth:`forget_past` keep the others read while near."""

    def __init__(self, demand, st) -> None:
        self.after: dict[str, frozenset] = {}  # vehicle -> the roads of its route past the last one a path takes
        self.live: dict[str, frozenset] = {}  # ... of those in SUMO's network now
        if not demand.background:
            return
        watched = {edge_of(ln) for mv in st.paths.values() for ln in mv.lanes if not ln.startswith(":")}
        past: dict[str, frozenset | None] = {}
        for key, edges in demand.background_routes.items():
            last = max((k for k, e in enumerate(edges) if e in watched), default=None)
            past[key] = None if last is None else frozenset(edges[last + 1:]) - watched
        st.sumo.unread = {vid for vid, key, *_ in demand.background if past[key] is None}
        self.after = {vid: past[key] for vid, key, *_ in demand.background if past[key] is not None}

    def departed(self, vid: str) -> None:
        """SUMO inserted ``vid`` in the last step."""
        if vid in self.after:
            self.live[vid] = self.after[vid]

    def forget_past(self, st) -> None:
        """Leave out of SUMO's reading the background vehicles past the last road of a path on their
        route (``st.snap``: this step's reading)."""
        tab = st.snap
        for vid, done in list(self.live.items()):
            k = tab.row.get(vid)
            if k is None:  # it left the network
                del self.live[vid]
            elif edge_of(tab.lane[k]) in done:
                st.sumo.forget(vid)
                del self.live[vid]
