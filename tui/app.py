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

import asyncio
import threading
import time
from collections import deque
from collections.abc import Sequence
from typing import Any, ClassVar

import zenoh
from textual import events
from textual.app import App, ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Container
from textual.css.query import NoMatches
from textual.geometry import Size
from textual.widgets import Footer

from qlap_runtime.bus import keys
from qlap_runtime.bus.config import client_config
from qlap_runtime.bus.schema import (
    ActionInfo,
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
    StatusBar,
    ViewTabs,
    WorldPanel,
    steps_done,
)

SPEEDS = (0.0, 1000.0, 300.0, 100.0, 30.0, 10.0, 3.0, 1.0)
"""The speed ladder of + and −, fastest first (0 = as fast as possible)."""

LATEST = ("knowledge", "calllist", "world", "status")

VIEWS = (("plans", "Plans"), ("iac", "IAC"), ("world", "World"), ("calllist", "Call list"),
         ("landmarks", "Landmarks"), ("counters", "Counters"), ("runtime", "Runtime"))
"""The panels below the actions in the compact layout, in the order ``v`` cycles them."""

WIDE = Size(144, 40)
"""The smallest terminal that gets every panel at once; below it (either way) the compact
layout shows the actions and one other panel at a time."""

PENDING_S = 3.0
"""How long a pressed key's intended state (pause, speed) counts before the agent's status
has confirmed it, so that quick presses build on each other instead of on a stale status."""


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
    #main { layout: grid; grid-size: 12 4; grid-rows: 1fr 7 1fr 10; }
    #main > * { height: 1fr; }
    #actions, #plans { column-span: 6; }
    #iac { column-span: 4; row-span: 2; }
    #calllist, #landmarks, #counters, #runtime { column-span: 4; }
    #world { column-span: 4; row-span: 3; }
    #viewtabs { display: none; }
    Screen.-compact #main { layout: vertical; }
    Screen.-compact #actions { height: 1fr; }
    Screen.-compact #viewtabs { display: block; height: 1; }
    Screen.-compact .view { display: none; height: 1fr; }
    Screen.-compact .view.-shown { display: block; }
    """
    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("p", "toggle_pause", "Pause"),
        Binding("s", "single_step", "Step"),
        Binding("plus,equals_sign", "faster", "Faster", key_display="+"),
        Binding("minus", "slower", "Slower", key_display="-"),
        Binding("c", "checkpoint", "Save"),
        Binding("g", "goal", "Goal"),
        Binding("v", "next_view", "View"),
        *(Binding(str(i), f"view('{key}')", name, show=False)
          for i, (key, name) in enumerate(VIEWS, 1)),
        Binding("question_mark", "help", "Help", key_display="?"),
        Binding("q", "quit", "Quit"),
    ]

    def __init__(self, session: zenoh.Session | None = None, *,
                 connect: Sequence[str] | str | None = None, run_id: str | None = None,
                 driver: Any = None, refresh_hz: float = 10.0,
                 quit_on: Sequence[int] = (), **client: Any) -> None:
        super().__init__()
        self._quit_on = tuple(quit_on)
        """Signals that quit the UI as ``q`` does (asyncio signal handlers, set on mount)."""
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
        self.compact = False
        """The compact layout (a terminal smaller than :data:`WIDE`) is on."""
        self.view = VIEWS[0][0]
        """The panel shown below the actions in the compact layout."""
        self._pending: dict[str, tuple[Any, float]] = {}

    # ----------------------------------------------------------------------------- layout
    def compose(self) -> ComposeResult:
        yield StatusBar(id="statusbar")
        with Container(id="main"):
            yield ActionsPanel(id="actions")
            yield ViewTabs(VIEWS, id="viewtabs")
            yield PlansPanel(id="plans", classes="view -shown")
            yield IACPanel(id="iac", classes="view")
            yield CallListPanel(id="calllist", classes="view")
            yield WorldPanel(id="world", classes="view")
            yield LandmarksPanel(id="landmarks", classes="view")
            yield CountersPanel(id="counters", classes="view")
            yield RuntimePanel(id="runtime", classes="view")
        yield Footer(show_command_palette=False)

    def _panel(self, cls):
        """A panel of the main screen, also while a dialog (goal, help) is on top;
        :class:`NoMatches` once the app is shutting down (its screens gone)."""
        if not self.screen_stack:
            raise NoMatches(f"no screen for {cls.__name__}: the app is shutting down")
        return self.screen_stack[0].query_one(cls)

    def on_mount(self) -> None:
        loop = asyncio.get_running_loop()
        for sig in self._quit_on:
            loop.add_signal_handler(sig, self.call_next, self.action_quit)
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
        bar = self._panel(StatusBar)
        bar.run_id = self.run_id or ""
        bar.show(None)
        self.sub_title = f"run {self.run_id or '(any)'}"
        self._set_layout(self.size)

    # ------------------------------------------------------------------ wide / compact layout
    def on_resize(self, event: events.Resize) -> None:
        self._set_layout(event.size)

    def _set_layout(self, size: Size) -> None:
        """The wide layout (every panel) from :data:`WIDE` up, else the compact one."""
        compact = size.width < WIDE.width or size.height < WIDE.height
        self.compact = compact
        try:
            screen = self.screen_stack[0]
            screen.set_class(compact, "-compact")
            screen.query_one(Footer).compact = compact
        except (IndexError, NoMatches):
            return
        self.refresh_bindings()

    def action_view(self, key: str) -> None:
        """Compact layout: show panel ``key`` below the actions."""
        if key not in dict(VIEWS):
            return
        self.view = key
        screen = self.screen_stack[0]
        for k, _ in VIEWS:
            screen.query_one(f"#{k}").set_class(k == key, "-shown")
        screen.query_one(ViewTabs).show(key)

    def action_next_view(self) -> None:
        order = [k for k, _ in VIEWS]
        self.action_view(order[(order.index(self.view) + 1) % len(order)])

    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        if action in ("next_view", "view") and not self.compact:
            return False                      # the wide layout shows every panel
        return True

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
            self._panel(StatusBar).run_id = self.run_id
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
            self._panel(StatusBar).show(self.status)
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
        try:
            self._show_plans(event.label)
        except NoMatches:       # a selection still queued when the app shut down
            self.log.debug("selection during shut-down skipped")

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

    def _intended(self, name: str, reported: Any) -> Any:
        """The state the user last asked for (``paused``, ``speed``) until the agent's status
        reports it (or :data:`PENDING_S` passes), else what the status reports."""
        pending = self._pending.get(name)
        if pending is None:
            return reported
        value, since = pending
        if value == reported or time.monotonic() - since > PENDING_S:
            del self._pending[name]
            return reported
        return value

    @property
    def run_finished(self) -> bool:
        """Whether the run's latest status says it finished (its outputs are written)."""
        return self.status is not None and self.status.finished

    def _finished(self, what: str) -> bool:
        """True (and says so) when the run is finished: nothing pauses or steps it."""
        if self.run_finished:
            self.notify(f"the run finished at step {steps_done(self.status.step)}: "
                        f"{what}", severity="warning")
            return True
        return False

    def action_toggle_pause(self) -> None:
        if self._finished("nothing to pause or resume"):
            return
        paused = self._intended("paused", self.status.paused if self.status else False)
        if self.send("resume" if paused else "pause"):
            self._pending["paused"] = (not paused, time.monotonic())

    def action_single_step(self) -> None:
        if self._finished("no more steps to take"):
            return
        if self.send("step", n=1):
            self._pending["paused"] = (True, time.monotonic())

    def _speed_index(self) -> int:
        speed = self._intended("speed", self.status.speed if self.status else 0.0)
        if speed <= 0:
            return 0
        return min(range(1, len(SPEEDS)), key=lambda i: abs(SPEEDS[i] - speed))

    def _set_speed(self, i: int) -> None:
        if self.send("speed", steps_per_s=SPEEDS[i]):
            self._pending["speed"] = (SPEEDS[i], time.monotonic())

    def action_faster(self) -> None:
        self._set_speed(max(0, self._speed_index() - 1))

    def action_slower(self) -> None:
        self._set_speed(min(len(SPEEDS) - 1, self._speed_index() + 1))

    def action_checkpoint(self) -> None:
        if self.send("save"):
            self.notify("checkpoint requested")

    def suggested_goal(self) -> tuple[ActionInfo | None, str]:
        """The action the goal dialog starts with, and why: the selected one once the user
        has chosen it, else the most reliable action that has a plan (rel(a), then calls)."""
        k = self.knowledge
        if k is None:
            return None, ""
        goals = [a for a in k.actions if a.variable in k.values and 0 <= a.index
                 < len(k.values[a.variable])]
        panel = self._panel(ActionsPanel)
        if not panel.follow_top:
            chosen = next((a for a in goals if a.label == panel.selected), None)
            if chosen is not None:
                return chosen, "the selected action"
        if not goals:
            return None, ""
        best = max(goals, key=lambda a: (bool(a.plans), a.rel, a.calls))
        return best, "the most reliable action"

    def action_goal(self) -> None:
        if self.knowledge is None:
            self.notify("no knowledge yet", severity="warning")
            return
        action, why = self.suggested_goal()
        suggested = [(action.variable, action.value)] if action else []
        hint = (f"pre-filled with {why}: {action.label}, rel(a) {action.rel:.2f}"
                if action else "")

        def done(choice: Any) -> None:
            if choice is False:
                return
            if choice is None:
                self.send("goal", clear=True)
            else:
                self.send("goal", var=choice[0], value=choice[1])

        self.push_screen(GoalScreen(dict(self.knowledge.values), suggested, hint), done)

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
