"""The TUI's panels, one per module (docs/tui.md)."""

from ._format import steps_done
from .actions import ActionsPanel
from .calllist import CallListPanel
from .counters import CountersPanel
from .goal import GoalScreen
from .help import HelpScreen
from .iac import IACPanel
from .landmarks import LandmarksPanel
from .plans import PlansPanel
from .runtime import RuntimePanel
from .statusbar import StatusBar, ViewTabs
from .world import WorldPanel

__all__ = ["ActionsPanel", "CallListPanel", "CountersPanel", "GoalScreen", "HelpScreen",
           "IACPanel", "LandmarksPanel", "PlansPanel", "RuntimePanel", "StatusBar", "ViewTabs",
           "WorldPanel", "steps_done"]
