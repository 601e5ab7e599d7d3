"""The bus: Zenoh configs, key expressions, message schemas, the trio bridge and the recorder.

Pure plumbing, independent of QLAP's algorithm (docs/bus.md). The algorithm
(:mod:`qlap_runtime.qlap`) never imports this package.
"""

from .bridge import AliveChange as AliveChange
from .bridge import AliveWatcher as AliveWatcher
from .bridge import Publisher as Publisher
from .bridge import Received as Received
from .bridge import RejectionCounter as RejectionCounter
from .bridge import StateQueryable as StateQueryable
from .bridge import TrioInbox as TrioInbox
from .bridge import TrioSubscriber as TrioSubscriber
from .bridge import declare_alive as declare_alive
from .bridge import fetch as fetch
from .config import BusConfigError as BusConfigError
from .config import TlsFiles as TlsFiles
from .config import acl_own_keys as acl_own_keys
from .config import client_config as client_config
from .config import config_from_file as config_from_file
from .config import embedded_config as embedded_config
from .config import router_config as router_config
from .keys import BusKeyError as BusKeyError
from .recorder import RecordSummary as RecordSummary
from .recorder import echo as echo
from .recorder import read_mcap as read_mcap
from .recorder import record as record
from .schema import CallList as CallList
from .schema import Control as Control
from .schema import DeltaMsg as DeltaMsg
from .schema import IACChoice as IACChoice
from .schema import Message as Message
from .schema import MessageError as MessageError
from .schema import Motor as Motor
from .schema import QState as QState
from .schema import Rejected as Rejected
from .schema import Sense as Sense
from .schema import Stats as Stats
from .schema import decode as decode
from .schema import encode as encode
from .schema import json_schema as json_schema
