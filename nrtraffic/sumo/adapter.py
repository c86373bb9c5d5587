"""The only place that talks to SUMO at run time (libsumo, in-process).

One simulation per process (a libsumo limitation): a :class:`SumoSession` is a context manager and
refuses to start while another session of the process is open.

Poses are pushed with ``moveToXY(keepRoute=3)``: bit 0 keeps the vehicle on its route (on the
route's internal lanes, too), bit 1 places the front bumper at the exact position, lateral offset
included, with or without the sublane model (``keepRoute=1`` needs the sublane model for that and
snaps to the lane centre without it: TraCI's moveToXY documentation, and
``tests/test_sumo_adapter.py``). Without sublanes SUMO's step costs
about a third less (docs/performance.md). The true speed is set beside it (``setSpeedMode 0`` +
``setSpeed``), so that SUMO's timeLoss and the cars behind see the real speed.
"""

from __future__ import annotations

import functools

import math
import operator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nrtraffic.sumo.network import edge_of

_ACTIVE = None
DEFAULT_SPEED_MODE = 31  # SUMO's default: all safety checks on
DEFAULT_LANE_CHANGE_MODE = 1621  # SUMO's default: strategic, cooperative, speed gain and keep-right changes
# strategic changes only (those its route needs), respecting the others' gaps; no cooperative, speed
# gain or keep-right changes
ROUTE_LANE_CHANGE_MODE = 0b10_00_00_00_01
KEEP_ROUTE_EXACT = 3  # moveToXY keepRoute bits: 1 keep the route, 2 the exact (lateral) position


class SumoError(RuntimeError):
    """SUMO refused a command or failed during a run."""


def _libsumo():
    try:
        import libsumo
    except ImportError as exc:  # pragma: no cover - dependency missing
        raise SumoError("libsumo is not installed (pip install libsumo)") from exc
    return libsumo


def sumo_version() -> str:
    """Version string of the SUMO wheel."""
    try:
        from importlib.metadata import version

        return version("eclipse-sumo")
    except Exception:  # pragma: no cover
        return "unknown"


def nav_angle(psi: float) -> float:
    """Heading [rad, counter-clockwise from +x] -> SUMO navigation angle [deg, 0 = north, clockwise]."""
    return (90.0 - math.degrees(psi)) % 360.0


def heading_from_nav(angle_deg: float) -> float:
    """SUMO navigation angle [deg] -> heading [rad, counter-clockwise from +x], in (-pi, pi]."""
    return math.atan2(math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg)))


@dataclass
class VehicleTable:
    """Every vehicle in the network at one instant, read in one batch (:meth:`SumoSession.snapshot`).

    ``ids`` and ``lane`` are lists, the rest arrays in the same order: ``lane_pos`` front-bumper
    position along the lane [m], ``x``, ``y`` front bumper [m], ``psi`` heading [rad],
    ``speed`` [m/s], ``accel`` longitudinal acceleration of the last step [m/s^2]; ``row`` maps an
    id to its row. ``derived`` holds what a reader works out from the table once per instant,
    under a name of its own (the edges where a car queues, for the exit check).
    """

    ids: list
    lane: list
    lane_pos: np.ndarray
    x: np.ndarray
    y: np.ndarray
    psi: np.ndarray
    speed: np.ndarray
    accel: np.ndarray
    row: dict
    derived: dict = field(default_factory=dict, repr=False, compare=False)

    @functools.cached_property
    def rows_by_edge(self) -> dict[str, list[int]]:
        """The rows on each edge (a lane's id less its ``_<index>``; a junction's internal lanes
        by their own ``:<junction>_<n>``), made once, when first asked."""
        rows: dict[str, list[int]] = {}
        for k, lane in enumerate(self.lane):
            rows.setdefault(edge_of(lane), []).append(k)
        return rows


@dataclass(frozen=True)
class VehicleType:
    """A SUMO vehicle type: geometry and SUMO's own driving. The controlled vehicles' type
    (``auto``) drives deterministically (``sigma = 0``, ``speedDev = 0``); human drivers (the
    ``[human]`` section) have the car-following model's imperfection ``sigma``, reaction time
    ``tau`` and a spread of desired speeds ``speed_dev``."""

    id: str = "auto"
    length_m: float = 4.8
    width_m: float = 1.9
    min_gap_m: float = 2.5
    accel_mps2: float = 2.6
    decel_mps2: float = 4.5
    max_speed_mps: float = 20.0
    sigma: float = 0.0  # driver imperfection (Krauss: random deceleration up to sigma * accel)
    tau_s: float = 1.0  # the driver's desired time headway [s]
    speed_dev: float = 0.0  # standard deviation of the desired speed / speed limit
    car_follow_model: str = "Krauss"

    def xml(self) -> str:
        return (f'<vType id="{self.id}" carFollowModel="{self.car_follow_model}" length="{self.length_m}" '
                f'width="{self.width_m}" minGap="{self.min_gap_m}" accel="{self.accel_mps2}" '
                f'decel="{self.decel_mps2}" maxSpeed="{self.max_speed_mps}" speedFactor="1" '
                f'speedDev="{self.speed_dev:g}" sigma="{self.sigma:g}" tau="{self.tau_s:g}"/>')


def handover_tau_s(spacing_m: float, headway_s: float, length_m: float, min_gap_m: float, v_max_mps: float,
                   step_s: float) -> float:
    """The desired headway ``tau`` [s] SUMO's car-following (Krauss) gives a controlled vehicle
    once it has left the merging zone, so that SUMO keeps the spacing the coordinator planned
    instead of braking a released platoon car after car (a wave that runs back into the merging
    zone and the control zone behind it: with SUMO's 1 s, 1 s merges at 13.89 m/s are too close).

    Krauss keeps speed behind a leader at the same speed ``v`` while the gap it sees (bumper to
    bumper, less ``minGap``) is at least ``tau v``: ``vsafe = -b tau + sqrt((b tau)^2 + v^2 + 2 b g)
    >= v`` if and only if ``g >= tau v``. Consecutive merges of a lane are ``max(delta, h_min v)``
    apart centre to centre (``spacing_m``, ``headway_s``), so ``tau`` is 0.9 of the lowest
    ``(max(delta, h_min v) - L - minGap) / v`` over ``0 < v <= v_max`` (reached at ``v_max`` or at
    ``v = delta / h_min``), at least one SUMO step and at most SUMO's default 1 s. *derived*"""
    speeds = [v_max_mps]
    if headway_s > 0.0 and 0.0 < spacing_m / headway_s < v_max_mps:
        speeds.append(spacing_m / headway_s)
    tau = min((max(spacing_m, headway_s * v) - length_m - min_gap_m) / v for v in speeds)
    return min(1.0, max(0.9 * tau, step_s))


def write_sumocfg(path: Path, network: Path, routes: Path, step_length_s: float, begin_s: float = 0.0) -> None:
    """A SUMO configuration that opens ``network`` with ``routes`` (``sumo-gui -c path``), paths
    relative to its own folder, starting at ``begin_s`` (SUMO's clock, ``scenario.begin_s``)."""
    import os
    from xml.sax.saxutils import quoteattr

    def rel(p):  # (escaped: a file name may hold an & or a <)
        return quoteattr(os.path.relpath(Path(p).resolve(), Path(path).resolve().parent))

    Path(path).write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n<configuration>\n'
        f'    <input>\n        <net-file value={rel(network)}/>\n        <route-files value={rel(routes)}/>\n'
        f'    </input>\n    <time>\n        <begin value="{begin_s:g}"/>\n        <step-length value="{step_length_s:g}"/>\n'
        '    </time>\n</configuration>\n')


def write_routes(path: Path, vtype, routes: dict[str, tuple[str, ...]], vehicles, t0_s: float = 0.0) -> None:
    """Write a SUMO route file.

    ``vtype``: a :class:`VehicleType`, or a list of them (the first is the default).
    ``vehicles``: iterable of ``(vehicle_id, route_name, depart_s, depart_speed_mps[, depart_pos_m[,
    type_id[, depart_lane]]])`` sorted by departure (``depart_lane``: SUMO's departLane, "best"
    where absent; ``depart_pos_m`` < 0 or absent: SUMO's ``base``, the vehicle
    just on the lane). The default type's speeds are deterministic (``speedFactor=1``,
    ``sigma=0``); randomness then comes from the arrival times only. ``t0_s``: SUMO's clock at the
    run's start, added to each departure (``depart_s`` is measured from the start) [s].
    """
    types = list(vtype) if isinstance(vtype, (list, tuple)) else [vtype]
    lines = ["<routes>"]
    lines += [f"    {t.xml()}" for t in types]
    for name, edges in routes.items():
        lines.append(f'    <route id="{name}" edges="{" ".join(edges)}"/>')
    for vid, route, depart, speed, *rest in vehicles:
        pos = rest[0] if rest and rest[0] >= 0 else "base"
        pos = pos if isinstance(pos, str) else f"{pos:.3f}"
        tid = rest[1] if len(rest) > 1 else types[0].id
        lane = rest[2] if len(rest) > 2 else "best"
        lines.append(
            f'    <vehicle id="{vid}" type="{tid}" route="{route}" depart="{depart + t0_s:.2f}" '
            f'departSpeed="{speed:.3f}" departPos="{pos}" departLane="{lane}"/>'
        )
    lines.append("</routes>")
    path.write_text("\n".join(lines) + "\n")


class SumoSession:
    """A running SUMO simulation.

    Parameters
    ----------
    net, routes : SUMO inputs.
    step_length_s : SUMO step [s].
    seed : SUMO's ``--seed``.
    lateral_resolution_m : sublane width [m]; 0 runs without the sublane model (SUMO's default).
    tripinfo, collisions, fcd : output files (None: not written). A name ending in .csv or
        .parquet selects that format (SUMO's own writers).
    gui : run in sumo-gui (shipped with eclipse-sumo) through TraCI instead of libsumo, to watch
        the run; slower, and needs a display.
    begin_s : SUMO's clock at the start (``--begin``) [s]; :attr:`time` is measured from it, the route
        file's departures are absolute (:func:`write_routes` ``t0_s``).
    gui_delay_ms : with ``gui``, the wall time each step takes at least [ms] (sumo-gui's delay:
        its own ``--delay`` does not act on steps that TraCI asks for), so that the vehicles can be
        followed by eye.
    """

    # colours of the vehicles in sumo-gui by their state in the run (RGBA); the legend is in the docs
    # (Watching a run) and in ``nrtraffic run --help``
    COLOURS = {"approaching": (160, 160, 160, 255), "held": (220, 40, 40, 255), "pending": (240, 180, 0, 255),
               "controlled": (30, 110, 230, 255), "released": (40, 170, 60, 255), "human": (150, 90, 200, 255),
               "human_reserved": (230, 110, 200, 255), "sumo": (255, 255, 255, 255)}
    GUI_CONNECT_TRIES = 60  # sumo-gui gets this many seconds to load the network and listen

    def __init__(self, net: Path, routes: Path, step_length_s: float, seed: int, lateral_resolution_m: float = 0.0,
                 tripinfo: Path | None = None, collisions: Path | None = None, fcd: Path | None = None,
                 extra_args: tuple[str, ...] = (), gui: bool = False, begin_s: float = 0.0,
                 gui_delay_ms: float = 100.0):
        self.gui = gui
        self.begin = float(begin_s)
        self.gui_delay_ms = float(gui_delay_ms)
        self._step_due = 0.0  # (gui) monotonic clock before which the next step is not taken [s]
        self.args = [
            "sumo",
            "--net-file", str(net),
            "--route-files", str(routes),
            "--step-length", repr(float(step_length_s)),
            "--seed", str(int(seed)),
            "--collision.action", "warn",
            "--collision.check-junctions", "true",
            "--collision.mingap-factor", "0",
            "--no-step-log", "true",
            "--no-warnings", "true",
            "--duration-log.disable", "true",
            "--time-to-teleport", "-1",
        ]
        if self.begin > 0:
            self.args += ["--begin", repr(self.begin)]
        if lateral_resolution_m > 0:
            self.args += ["--lateral-resolution", repr(float(lateral_resolution_m))]
        if tripinfo is not None:
            self.args += ["--tripinfo-output", str(tripinfo)]
        if collisions is not None:
            self.args += ["--collision-output", str(collisions)]
        if fcd is not None:
            self.args += ["--fcd-output", str(fcd), "--fcd-output.acceleration", "true"]
        self.args += list(extra_args)
        self.step_length = float(step_length_s)
        self.traci = None
        self._pending_moves = False
        self._stepped = False  # (see :meth:`snapshot`)
        self.unread: set[str] = set()  # vehicles never subscribed: left out of every snapshot
        from libsumo import constants as tc

        self._vars = (tc.VAR_LANE_ID, tc.VAR_LANEPOSITION, tc.VAR_POSITION, tc.VAR_ANGLE, tc.VAR_SPEED,
                      tc.VAR_ACCELERATION)
        self._pick = operator.itemgetter(*self._vars)  # a subscription result -> its values in that order

    # ---- life cycle
    def start(self) -> "SumoSession":
        global _ACTIVE
        if _ACTIVE is not None:
            raise SumoError("a SUMO simulation is already running in this process (libsumo allows one)")
        if self.gui:
            t = self._start_gui()
        else:
            t = _libsumo()
            try:
                t.start(self.args)
            except Exception as exc:
                raise SumoError(f"SUMO failed to start: {exc}") from None
        self.traci = t
        self._stepped = False
        _ACTIVE = self
        return self

    def _start_gui(self):
        """sumo-gui, started here and connected to by TraCI. When it stops before it listens (it
        cannot open the display, say), the error says why, from its own output, at once (TraCI's
        ``start`` would start it again, 60 times)."""
        import contextlib
        import io
        import subprocess
        import tempfile

        import traci
        from sumolib.miscutils import getFreeSocketPort

        from nrtraffic.sumo.netbuild import sumo_binary

        port = getFreeSocketPort()
        args = [sumo_binary("sumo-gui"), *self.args[1:], "--start", "true", "--quit-on-end", "true",
                "--window-size", "1200,900", "--remote-port", str(port)]
        log = tempfile.TemporaryFile()
        try:
            proc = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT)
        except OSError as exc:
            log.close()
            raise SumoError(f"sumo-gui failed to start: {exc}") from None
        try:
            with contextlib.redirect_stdout(io.StringIO()):  # (TraCI prints a line per second it waits)
                traci.init(port, numRetries=self.GUI_CONNECT_TRIES, proc=proc)
        except BaseException as exc:  # (Ctrl-C or SIGTERM while it connects too: sumo-gui is not left running)
            if proc.poll() is None:
                proc.kill()
            proc.wait()
            if not isinstance(exc, Exception):
                raise
            log.seek(0)
            said = log.read().decode(errors="replace").strip()[-1500:]
            raise SumoError(f"sumo-gui stopped before the run could start (exit status {proc.returncode}; {exc})"
                            + (f": {said}" if said else "") + ". It needs a display it can open: check DISPLAY, "
                            "or run under a virtual one with xvfb-run -a") from None
        finally:
            log.close()
        return traci

    def show(self, xmin: float, ymin: float, xmax: float, ymax: float) -> tuple[float, float, float, float] | None:
        """In sumo-gui, show the rectangle ``[xmin, xmax] x [ymin, ymax]`` [m, network coordinates];
        returns what its view shows then (the rectangle widened to the window's shape), or None
        without the GUI."""
        if not self.gui:
            return None
        view = self.traci.gui.DEFAULT_VIEW
        self.traci.gui.setBoundary(view, xmin, ymin, xmax, ymax)
        (x0, y0), (x1, y1) = self.traci.gui.getBoundary(view)
        return x0, y0, x1, y1

    def close(self) -> None:
        global _ACTIVE
        if self.traci is not None:
            if self._pending_moves:
                # libsumo keeps moveToXY requests in process-wide state until the next step: closing
                # with requests pending leaves them dangling and crashes the next simulation of the
                # process. Let SUMO consume them first.
                try:
                    self.traci.simulationStep()
                except Exception:
                    pass
            try:
                self.traci.close()
            except Exception:
                pass
            self.traci = None
        if _ACTIVE is self:
            _ACTIVE = None

    def __enter__(self) -> "SumoSession":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # ---- stepping
    def step(self) -> float:
        """Advance SUMO by one step; returns the new simulation time [s]. In sumo-gui, not sooner
        than ``gui_delay_ms`` after the last step."""
        if self.gui and self.gui_delay_ms > 0:
            import time

            now = time.monotonic()
            if now < self._step_due:
                time.sleep(self._step_due - now)
            self._step_due = max(now, self._step_due) + self.gui_delay_ms / 1000.0
        try:
            self.traci.simulationStep()
        except Exception as exc:
            raise SumoError(f"SUMO step failed at t={self.time:.2f} s: {exc}") from None
        self._pending_moves = False
        self._stepped = True
        return self.time

    @property
    def time(self) -> float:
        """Simulated time since the run's start [s] (SUMO's clock less ``begin_s``)."""
        return self.traci.simulation.getTime() - self.begin

    def departed(self) -> tuple[str, ...]:
        """Vehicles inserted in the last step; each (but those in :attr:`unread`) is subscribed to
        the variables that :meth:`snapshot` reads."""
        ids = self.traci.simulation.getDepartedIDList()
        sub = self.traci.vehicle.subscribe
        for vid in ids:
            if vid in self.unread:
                continue
            sub(vid, self._vars)
            if self.gui:  # driven by SUMO until the run says otherwise (:meth:`colour`)
                self.traci.vehicle.setColor(vid, self.COLOURS["sumo"])
        return ids

    def forget(self, vid: str) -> None:
        """Leave a vehicle out of :meth:`snapshot` from the next step on (it stays in SUMO)."""
        self.traci.vehicle.unsubscribe(vid)

    def depart_delay(self, vid: str) -> float:
        """How long SUMO waited to insert a vehicle past its desired departure (its lane was
        backed up) [s]; SUMO's departDelay."""
        return float(self.traci.vehicle.getDepartDelay(vid))

    def snapshot(self) -> VehicleTable:
        """Lane, lane position, front-bumper pose, speed and acceleration of every vehicle in the
        network (but those :meth:`forget` left out), from one batched read of SUMO's subscriptions
        (updated by every step). Before the first step it is empty: libsumo still holds the results
        of the last simulation this process ran until then (a sweep's worker runs one after
        another), whose vehicles would stand in this one's network at t = 0."""
        res = self.traci.vehicle.getAllSubscriptionResults() if self._stepped else {}
        ids = list(res)
        if not ids:
            none = np.zeros(0)
            return VehicleTable(ids, [], none, none, none, none, none, none, {})
        # one tuple per vehicle in the order of self._vars, transposed to one tuple per variable
        lane, lane_pos, xy, nav, speed, accel = zip(*map(self._pick, res.values()))
        num = np.array((lane_pos, nav, speed, accel), dtype=float)
        xy = np.array(xy, dtype=float)
        ang = np.radians(num[1])
        psi = np.arctan2(np.cos(ang), np.sin(ang))  # navigation angle -> heading (heading_from_nav)
        return VehicleTable(ids, list(lane), num[0], xy[:, 0], xy[:, 1], psi, num[2], num[3],
                            dict(zip(ids, range(len(ids)))))

    def arrived(self) -> tuple[str, ...]:
        return self.traci.simulation.getArrivedIDList()

    def vehicle_ids(self) -> tuple[str, ...]:
        return self.traci.vehicle.getIDList()

    def pending(self) -> int:
        """Vehicles still in the network or waiting to depart."""
        return self.traci.simulation.getMinExpectedNumber()

    # ---- network
    def route_lanes(self, edges, first_lane: int = 0,
                    lane_to: int | None = None) -> list[tuple[str, list[tuple[float, float]], float]]:
        """The lanes a vehicle drives along ``edges``, starting on lane ``first_lane`` of the first
        and following SUMO's connections from lane to lane (junction-internal lanes included):
        ``[(lane_id, shape, sumo_length), ...]``. ``lane_to``: the lane index to take on the second
        edge, where the first lane connects to several (default: the first connection)."""
        t = self.traci
        out = []
        lane = f"{edges[0]}_{first_lane}"
        for k, e in enumerate(edges):
            out.append((lane, list(t.lane.getShape(lane)), t.lane.getLength(lane)))
            if k + 1 < len(edges):
                nxt = edges[k + 1]
                via = target = None
                for link in t.lane.getLinks(lane):
                    if edge_of(link[0]) == nxt and (
                            k > 0 or lane_to is None or link[0] == f"{nxt}_{lane_to}"):
                        target, via = link[0], link[4]
                        break
                if via is None:
                    raise SumoError(f"lane {lane!r} has no connection to edge {nxt!r}")
                # an internal lane may be split in pieces (a left turn waiting inside the junction):
                # the next piece is the "via" of the internal lane's own link
                while via and via.startswith(":"):
                    out.append((via, list(t.lane.getShape(via)), t.lane.getLength(via)))
                    links = t.lane.getLinks(via)
                    nxt_via = links[0][4] if links else ""
                    via = nxt_via if nxt_via and nxt_via.startswith(":") else None
                lane = target
        return out

    def edge_length(self, edge: str) -> float:
        """Length of an edge's longest lane [m]."""
        t = self.traci
        return max(t.lane.getLength(f"{edge}_{i}") for i in range(t.edge.getLaneNumber(edge)))

    def lane_speed(self, lane: str) -> float:
        """Speed limit of a lane [m/s] (on junction-internal lanes SUMO derives it from the curvature)."""
        return self.traci.lane.getMaxSpeed(lane)

    # ---- vehicles
    def front_pose(self, vid: str) -> tuple[float, float, float]:
        """Front-bumper position [m] and heading [rad]."""
        x, y = self.traci.vehicle.getPosition(vid)
        return x, y, heading_from_nav(self.traci.vehicle.getAngle(vid))

    def speed(self, vid: str) -> float:
        return self.traci.vehicle.getSpeed(vid)

    def acceleration(self, vid: str) -> float:
        """Longitudinal acceleration in the last step [m/s^2]."""
        return self.traci.vehicle.getAcceleration(vid)

    def lane_position(self, vid: str) -> tuple[str, float]:
        """(lane id, front-bumper position along it [m])."""
        return self.traci.vehicle.getLaneID(vid), self.traci.vehicle.getLanePosition(vid)

    def colour(self, vid: str, state: str) -> None:
        """In sumo-gui, colour a vehicle by its state (:attr:`COLOURS`); nothing without the GUI."""
        if self.gui:
            self.traci.vehicle.setColor(vid, self.COLOURS[state])

    def hold_speed(self, vid: str, speed: float) -> None:
        """Let SUMO drive the vehicle at a fixed desired speed (safety checks stay on)."""
        self.traci.vehicle.setSpeed(vid, speed)

    def keep_lane(self, vid: str) -> None:
        """Let SUMO's driver make no lane change (lane-change mode 0): the vehicle stays on the
        lane it was inserted on."""
        self.traci.vehicle.setLaneChangeMode(vid, 0)

    def free_lane(self, vid: str) -> None:
        """Let SUMO's driver change lanes as it would on its own (SUMO's default lane-change mode:
        strategic changes for its route, cooperative, for speed, keeping right)."""
        self.traci.vehicle.setLaneChangeMode(vid, DEFAULT_LANE_CHANGE_MODE)

    def lanes_for_route(self, vid: str) -> None:
        """A vehicle :meth:`keep_lane` kept, past the last junction of its trip: SUMO's driver makes
        the lane changes its route needs again (:data:`ROUTE_LANE_CHANGE_MODE`). Kept on its lane to
        the end, it would stop for ever where its lane does not lead on to its route's next road
        (no teleport: the queue behind it would reach back through the junction). A vehicle that
        was never kept (SUMO's own lane-change mode) is left as it is."""
        v = self.traci.vehicle
        if v.getLaneChangeMode(vid) == 0:
            v.setLaneChangeMode(vid, ROUTE_LANE_CHANGE_MODE)

    def stop_at(self, vid: str, lane: str, pos_m: float) -> None:
        """Make SUMO's driver stop with its front bumper at ``pos_m`` [m] on ``lane`` (a lane of a
        normal edge) and wait there until :meth:`resume`; from then on it disregards the right of
        way at the junction and the vehicles already inside it (speed mode 55: every other check
        stays on), which the coordinator's reservation gives it instead: SUMO would otherwise brake
        in the junction for a foe whose reserved crossing the reservation already keeps apart, and
        come out later than reserved. Where it is already too close to brake for that stop (SUMO
        refuses it), it is told to stop as soon as it can instead."""
        edge, index = lane.rsplit("_", 1)
        v = self.traci.vehicle
        try:
            v.setStop(vid, edge, pos=float(pos_m), laneIndex=int(index), duration=1e7)
        except self.traci.TraCIException:  # too close to brake for it: it stops as soon as it can
            v.setSpeed(vid, 0.0)
        v.setSpeedMode(vid, (DEFAULT_SPEED_MODE & ~8) | 32)

    def is_stopped(self, vid: str) -> bool:
        """Whether a vehicle stands at a stop given by :meth:`stop_at`."""
        return bool(self.traci.vehicle.isStopped(vid))

    def speed_factor(self, vid: str) -> float:
        """The vehicle's drawn speed factor: its desired speed over the speed limit."""
        return float(self.traci.vehicle.getSpeedFactor(vid))

    def cancel_stop(self, vid: str) -> None:
        """Drop the stop of :meth:`stop_at` before the vehicle reaches it (nothing to drop where
        SUMO had refused it)."""
        if self.traci.vehicle.getStops(vid, 1):
            self.traci.vehicle.replaceStop(vid, 0, "")

    def leader(self, vid: str, dist_m: float) -> str | None:
        """The vehicle ahead of ``vid`` on the lanes it will take, within ``dist_m`` [m] of its front
        bumper (SUMO's leader search, which may look further: those further are left out), or None."""
        found = self.traci.vehicle.getLeader(vid, float(dist_m))
        return found[0] if found and found[0] and found[1] <= dist_m else None

    def resume(self, vid: str) -> None:
        """End the stop of :meth:`stop_at`: SUMO's driver sets off."""
        self.traci.vehicle.resume(vid)

    def take_over(self, vid: str) -> None:
        """Make a vehicle remote-controlled: speed mode 0, so that SUMO does not cap the speeds
        :meth:`push_pose` sets (once per vehicle; :meth:`release` restores it)."""
        self.traci.vehicle.setSpeedMode(vid, 0)

    def push_pose(self, vid: str, x_front: float, y_front: float, psi: float, speed: float) -> None:
        """Place a remote-controlled vehicle (:meth:`take_over`): front bumper at (x, y) [m],
        heading psi [rad], true speed [m/s]."""
        self.push_poses([vid], [x_front], [y_front], [psi], [speed])

    def push_poses(self, ids, x_front, y_front, psi, speed) -> None:
        """:meth:`push_pose` for many vehicles (arrays in the order of ``ids``)."""
        v = self.traci.vehicle
        set_speed, move = v.setSpeed, v.moveToXY
        nav = (90.0 - np.degrees(np.asarray(psi, dtype=float))) % 360.0  # nav_angle
        spd = np.maximum(np.asarray(speed, dtype=float), 0.0)
        self._pending_moves = True
        for vid, x, y, a, sp in zip(ids, np.asarray(x_front, float).tolist(), np.asarray(y_front, float).tolist(),
                                    nav.tolist(), spd.tolist()):
            try:
                set_speed(vid, sp)
                move(vid, "", 0, x, y, a, KEEP_ROUTE_EXACT)
            except Exception as exc:
                raise SumoError(f"moveToXY of {vid} failed at t={self.time:.2f} s: {exc}") from None

    def release(self, vid: str, tau_s: float | None = None) -> None:
        """Hand a vehicle back to SUMO's own driving; ``tau_s``: its desired headway [s] from now
        on (:func:`handover_tau_s`), or its type's."""
        v = self.traci.vehicle
        v.setSpeedMode(vid, DEFAULT_SPEED_MODE)
        v.setSpeed(vid, -1)
        if tau_s is not None:
            v.setTau(vid, tau_s)

    def collisions(self) -> list[tuple[str, str, str]]:
        """Collisions SUMO detected in the last step: (collider, victim, type)."""
        return [(c.collider, c.victim, c.type) for c in self.traci.simulation.getCollisions()]


def drive_alone(net: Path, routes: Path, step_length_s: float, seed: int, until_s: float,
                lateral_resolution_m: float = 0.0, read: bool = False) -> float:
    """SUMO alone on a route file, every vehicle driven by SUMO, for ``until_s`` simulated seconds
    (the reference a co-simulation's speed is measured against); returns the wall time [s]. With
    ``read``, every vehicle is also read after each step as a run reads them (subscribed on
    departure, :meth:`SumoSession.snapshot`): what the coupling costs before any control."""
    import time

    t0 = time.perf_counter()
    with SumoSession(net, routes, step_length_s, seed, lateral_resolution_m) as sumo:
        while sumo.time < until_s - 1e-9:
            sumo.step()
            if read:
                sumo.departed()
                sumo.snapshot()
    return time.perf_counter() - t0
