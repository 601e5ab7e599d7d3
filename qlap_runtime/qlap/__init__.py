"""The QLAP algorithm: pure, synchronous and deterministic (no I/O, no zenoh/trio/textual/physics).

Reference: J. Mugan, *Autonomous Qualitative Learning of Distinctions and Actions in a Developing
Agent*, PhD dissertation, UT Austin, 2010; each module cites the sections it implements.
"""

from .delta import Delta as Delta
from .learner import ModelLearner as ModelLearner
from .params import Ablations as Ablations
from .params import Params as Params
from .perception import InvalidObservation as InvalidObservation
from .perception import Percept as Percept
from .quantity import Landmark as Landmark
from .quantity import QuantitySpace as QuantitySpace
from .variables import Event as Event
from .variables import Kind as Kind
from .variables import VariableTable as VariableTable
