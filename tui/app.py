"""The QLAP terminal UI: a Zenoh subscriber and a Control publisher, nothing more.

:class:`QlapApp` subscribes to ``qlap/<run>/**`` (every run when ``run_id`` is None: it adopts
the first run it hears) and to the liveliness tokens, and publishes
:class:`~qlap_runtime.bus.schema.Control` on ``qlap/<run>/control``. It knows the agent only
through bus messages (docs/tui.md), so it watches the local driver (``tui/driver.py``) and,
later, the actor runtime alike.

Zenoh callbacks run on Zenoh's threads, or synchronously in the agent's thread when both share
an embedded session, so they only store the payload in :class:`BusFeed` (latest per topic; IAC
choices appended; a lock, no decoding). A 10 Hz timer on Textual's loop drains the feed, decodes
and updates the panels: the agent never waits for the UI, and a burst costs one refresh.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Sequence
from typing import Any, ClassVar

import zenoh
from textual.app import App, ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Container, Vertical
from textual.css.query import NoMatches
from textual.widgets import Footer, Header

from qlap_runtime.bus import keys
from qlap_runtime.bus.config import client_config
from qlap_runtime.bus.schema import (
    AgentStatus,
    CallList,
    Control,
    Knowledge,
    MessageError,
    Stats,
    WorldView,
    decode,
    encode,
)

from .widgets import (
    ActionsPanel,
    CallListPanel,
    CountersPanel,
    GoalScreen,
    HelpScreen,
    IACPanel,
    LandmarksPanel,
    PlansPanel,
    RuntimePanel,
    WorldPanel,
)

SPEEDS = (0.0, 1000.0, 300.0, 100.0, 30.0, 10.0, 3.0, 1.0)
"""The speed ladder of + and −, fastest first (0 = as fast as possible)."""

LATEST = ("knowledge", "calllist", "world", "status")


class BusFeed:
    """What the Zenoh callbacks leave for the UI: the latest payload per topic, the IAC choices
    since the last drain (at most ``iac_max``), stats per actor, liveliness changes.

    Invariant: callbacks only take the lock and store bytes; decoding happens in :meth:`drain`
    on the UI's loop.
    """

    def __init__(self, iac_max: int = 500) -> None:
        self._lock = threading.Lock()
        self._latest: dict[str, tuple[str, bytes]] = {}
        self._iac: deque[tuple[str, bytes]] = deque(maxlen=iac_max)
        self._stats: deque[tuple[str, bytes]] = deque(maxlen=64)
        self._alive: list[tuple[str, bool]] = []
        self.received = 0
        self.rejected = 0
        self.run_id: str | None = None

    def on_sample(self, sample: zenoh.Sample) -> None:
        try:
            key = str(sample.key_expr)
            run, topic = keys.parse(key)
        except keys.BusKeyError:
            return
        payload = sample.payload.to_bytes()
        with self._lock:
            self.received += 1
            if self.run_id is None:
                self.run_id = run
            elif run != self.run_id:
                return
            if topic == "iac":
                self._iac.append((key, payload))
            elif topic == "stats":
                self._stats.append((key, payload))
            elif topic in LATEST:
                self._latest[topic] = (key, payload)

    def on_alive(self, sample: zenoh.Sample) -> None:
        actor = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._lock:
            self._alive.append((actor, sample.kind == zenoh.SampleKind.PUT))

    def drain(self) -> tuple[dict[str, Any], list[Any], list[Any], list[tuple[str, bool]]]:
        """Decoded (latest by topic, IAC choices oldest first, stats, liveliness changes)."""
        with self._lock:
            latest, self._latest = self._latest, {}
            iac = list(self._iac)
            self._iac.clear()
            stats = list(self._stats)
            self._stats.clear()
            alive, self._alive = self._alive, []
        return ({t: m for t, (k, p) in latest.items() if (m := self._decode(k, p)) is not None},
                [m for k, p in iac if (m := self._decode(k, p)) is not None],
                [m for k, p in stats if (m := self._decode(k, p)) is not None], alive)

    def _decode(self, key: str, payload: bytes) -> Any:
        try:
            return decode(key, payload)
        except MessageError:
            self.rejected += 1
            return None


class QlapApp(App):
    """Watch and steer a QLAP agent over Zenoh.

    Args:
        session: an open session to use (not closed by the app), e.g. the local driver's.
        connect: router endpoint(s) to open a client session on (closed on exit).
        run_id: the run to watch (None: the first run heard).
        driver: a :class:`~tui.driver.LocalDriver` the app owns: its session is used and it is
            stopped when the app exits.
        refresh_hz: how often the panels are refreshed from the feed.
    """

    TITLE = "QLAP"
    CSS = """
    #main { layout: grid; grid-size: 6 3; grid-rows: 2fr 1fr 1fr; }
    #actions { column-span: 3; }
    #plans { column-span: 3; }
    #iac, #middle, #world, #counters, #runtime { column-span: 2; }
    #middle { layout: vertical; }
    #world { row-span: 2; }
    """
    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("p", "toggle_pause", "Pause/Resume"),
        Binding("s", "single_step", "Step"),
        Binding("plus,equals_sign", "faster", "+Speed", key_display="+"),
        Binding("minus", "slower", "-Speed", key_display="-"),
        Binding("c", "checkpoint", "Checkpoint"),
        Binding("g", "goal", "Goal"),
        Binding("question_mark", "help", "Help", key_display="?"),
        Binding("q", "quit", "Quit"),
    ]

    def __init__(self, session: zenoh.Session | None = None, *,
                 connect: Sequence[str] | str | None = None, run_id: str | None = None,
                 driver: Any = None, refresh_hz: float = 10.0, **client: Any) -> None:
        super().__init__()
        if driver is not None:
            session = driver.session
            run_id = run_id or driver.run_id
        if session is None and connect is None:
            raise ValueError("give a session, connect endpoint(s) or a driver")
        self._session = session
        self._own_session = session is None
        self._connect = connect
        self._client = client
        self.driver = driver
        self.run_id = keys.validate_run_id(run_id) if run_id else None
        self.refresh_hz = refresh_hz
        self.feed = BusFeed()
        self.feed.run_id = self.run_id
        self.knowledge: Knowledge | None = None
        self.status: AgentStatus | None = None
        self.calllist: CallList | None = None
        self.world: WorldView | None = None
        self.stats: dict[str, Stats] = {}
        self.alive: set[str] = set()
        self.iac_seen = 0
        self.refreshes = 0
        self._handles: list[Any] = []
        self._control_pub: Any = None
        self._closed = False
        self._refresh_timer: Any = None

    # ----------------------------------------------------------------------------- layout
    def compose(self) -> ComposeResult:
        yield Header(show_clock=False)
        with Container(id="main"):
            yield ActionsPanel(id="actions")
            yield PlansPanel(id="plans")
            yield IACPanel(id="iac")
            with Vertical(id="middle"):
                yield CallListPanel(id="calllist")
                yield LandmarksPanel(id="landmarks")
            yield WorldPanel(id="world")
            yield CountersPanel(id="counters")
            yield RuntimePanel(id="runtime")
        yield Footer()

    def _panel(self, cls):
        """A panel of the main screen, also while a dialog (goal, help) is on top."""
        return self.screen_stack[0].query_one(cls)

    def on_mount(self) -> None:
        if self._session is None:
            self._session = zenoh.open(client_config(self._connect, **self._client))
        session = self._session
        pattern = keys.run_pattern(self.run_id)
        self._handles.append(session.declare_subscriber(pattern, self.feed.on_sample))
        self._alive_pattern = (keys.alive_pattern(self.run_id) if self.run_id
                               else f"{keys.ROOT}/*/{keys.ALIVE}/*")
        self._handles.append(session.liveliness().declare_subscriber(
            self._alive_pattern, self.feed.on_alive, history=True))
        runtime = self._panel(RuntimePanel)
        runtime.run_id = self.run_id or "?"
        runtime.connection = ("embedded session" if not self._own_session
                              else ", ".join([self._connect] if isinstance(self._connect, str)
                                             else list(self._connect or ())))
        runtime.show()
        self.sub_title = f"run {self.run_id or '(any)'}"

    def on_ready(self) -> None:
        # Start draining only once every panel has composed its children (``Ready`` comes
        # after the first screen is mounted and painted; ``Mount`` may come before that).
        self._refresh_timer = self.set_interval(1.0 / self.refresh_hz, self.refresh_from_bus)

    # ----------------------------------------------------------------------------- updates
    def refresh_from_bus(self) -> None:
        """Drain the feed and update the panels (the 10 Hz timer).

        The timer starts on ``Ready`` (every panel composed); a tick that races with the
        app's shut-down is skipped instead of crashing it."""
        if self._closed or not self.screen_stack or not self.screen_stack[0].is_mounted:
            return
        try:
            self._update_panels(*self.feed.drain())
        except NoMatches:
            # Textual removes the widgets before it stops the app's timers: a tick during
            # shut-down finds no panel (nothing is lost that anyone could still see).
            self.log.debug("refresh during shut-down skipped")

    def _update_panels(self, latest: dict[str, Any], iac: list[Any], stats: list[Stats],
                       alive: list[tuple[str, bool]]) -> None:
        self.refreshes += 1
        if self.run_id is None and self.feed.run_id is not None:
            self.run_id = self.feed.run_id
            self.sub_title = f"run {self.run_id}"
            self._panel(RuntimePanel).run_id = self.run_id
        for actor, up in alive:
            (self.alive.add if up else self.alive.discard)(actor)
        for s in stats:
            self.stats[s.actor] = s
        if iac:
            self.iac_seen += len(iac)
            self._panel(IACPanel).add(iac)
            last = next((c for c in reversed(iac) if not c.babbling), None)
            if last is not None and not (self.calllist and self.calllist.actions):
                self._panel(ActionsPanel).set_practised(last.action)
        if "knowledge" in latest:
            self.apply_knowledge(latest["knowledge"])
        if "calllist" in latest:
            self.calllist = latest["calllist"]
            self._panel(CallListPanel).update_calllist(self.calllist)
            if self.calllist.actions:
                self._panel(ActionsPanel).set_practised(self.calllist.actions[0])
        if "world" in latest:
            self.world = latest["world"]
            self._panel(WorldPanel).update_world(self.world)
            self._panel(CallListPanel).update_calllist(motor=self.world.motor)
        if "status" in latest:
            self.status = latest["status"]
            self._panel(CallListPanel).update_calllist(goal=self.status.goal)
        if "status" in latest or alive or stats:
            self._panel(RuntimePanel).show(self.status, self.alive, self.stats)

    def apply_knowledge(self, k: Knowledge) -> None:
        self.knowledge = k
        actions = self._panel(ActionsPanel)
        actions.update_knowledge(k)
        self._panel(IACPanel).update_knowledge(k)
        self._panel(LandmarksPanel).update_knowledge(k)
        self._panel(CountersPanel).update_knowledge(k)
        self._show_plans(actions.selected)

    def _show_plans(self, label: str) -> None:
        if self.knowledge is None:
            return
        action = next((a for a in self.knowledge.actions if a.label == label), None)
        self._panel(PlansPanel).show(action)

    def on_actions_panel_selected(self, event: ActionsPanel.Selected) -> None:
        self._show_plans(event.label)

    # ----------------------------------------------------------------------------- control
    def send(self, command: str, **args: Any) -> bool:
        """Publish a :class:`Control` command to the run (False when no run is known yet)."""
        if self.run_id is None or self._session is None:
            self.notify("no agent heard yet", severity="warning")
            return False
        if self._control_pub is None:
            self._control_pub = self._session.declare_publisher(
                keys.key(self.run_id, "control"), encoding=zenoh.Encoding.APPLICATION_JSON,
                congestion_control=zenoh.CongestionControl.BLOCK)
        self._control_pub.put(encode(Control(command, args)))  # type: ignore[arg-type]
        return True

    def action_toggle_pause(self) -> None:
        paused = self.status.paused if self.status else False
        self.send("resume" if paused else "pause")

    def action_single_step(self) -> None:
        self.send("step", n=1)

    def _speed_index(self) -> int:
        speed = self.status.speed if self.status else 0.0
        if speed <= 0:
            return 0
        return min(range(1, len(SPEEDS)), key=lambda i: abs(SPEEDS[i] - speed))

    def action_faster(self) -> None:
        i = self._speed_index()
        self.send("speed", steps_per_s=SPEEDS[max(0, i - 1)])

    def action_slower(self) -> None:
        i = self._speed_index()
        self.send("speed", steps_per_s=SPEEDS[min(len(SPEEDS) - 1, i + 1)])

    def action_checkpoint(self) -> None:
        if self.send("save"):
            self.notify("checkpoint requested")

    def action_goal(self) -> None:
        if self.knowledge is None:
            self.notify("no knowledge yet", severity="warning")
            return
        suggested = []
        selected = self._panel(ActionsPanel).selected
        for a in self.knowledge.actions:
            if a.label == selected and a.variable in self.knowledge.values:
                suggested.append((a.variable, a.value))

        def done(choice: Any) -> None:
            if choice is False:
                return
            if choice is None:
                self.send("goal", clear=True)
            else:
                self.send("goal", var=choice[0], value=choice[1])

        self.push_screen(GoalScreen(dict(self.knowledge.values), suggested), done)

    def action_help(self) -> None:
        self.push_screen(HelpScreen())

    async def action_quit(self) -> None:
        self.close_bus()
        self.exit()

    # ----------------------------------------------------------------------------- closing
    def close_bus(self) -> None:
        """Undeclare everything, close the session if the app opened it, stop an owned driver.
        Idempotent; also runs on unmount."""
        if self._closed:
            return
        self._closed = True
        if self._refresh_timer is not None:
            self._refresh_timer.stop()
        for h in [*self._handles, self._control_pub]:
            if h is None:
                continue
            try:
                h.undeclare()
            except zenoh.ZError:  # pragma: no cover
                pass
        self._handles, self._control_pub = [], None
        if self.driver is not None:
            self.driver.stop()
        elif self._own_session and self._session is not None:
            self._session.close()
        self._session = None

    def on_unmount(self) -> None:
        self.close_bus()
