"""Measuring what a run learned: learning curves over its checkpoints (``qlap curve``, §7.2)
and its knowledge beside the reference's (``qlap report``, ch. 8), after J. Mugan, *Autonomous
Qualitative Learning of Distinctions and Actions in a Developing Agent*, PhD dissertation, UT
Austin, 2010. Documented in docs/analysis.md.
"""

from .runs import AnalysisError as AnalysisError

__all__ = ["AnalysisError"]
