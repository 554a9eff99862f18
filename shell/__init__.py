"""The services' shell: the bus and what every service does on it (docs/architecture.md "Layers").

Between the vocabulary (:mod:`formation`, no Zenoh) and the services. A service talks to
a :class:`Bus`: :class:`ZenohBus` in the product, :class:`MemoryBus` in unit tests; its
node runs one loop under a :class:`TimePolicy`, :class:`Lockstep` or :class:`Realtime`, and
takes its inputs from the policy's :class:`PhaseInbox`.
"""

from shell.bus import (
    Bus,
    MemoryBus,
    Publisher,
    Query,
    Sample,
    ZenohBus,
)
from shell.config_files import check_readable
from shell.inbox import PhaseInbox
from shell.loop import Loop
from shell.service import Incoming, Service, settle_heap
from shell.serving import (
    load_scenario,
    open_service,
    scenario_or_report,
    serve,
    service_parser,
    stop_on_signals,
)
from shell.stack_dump import DUMP_SIGNAL, dump_stacks_on_signal
from shell.timing import Lockstep, Realtime, TimePolicy, time_policy
from shell.zenoh_config import (
    MEMBER_ENV,
    MEMBERS_ENV,
    MEMBERS_FILE_ENV,
    add_arguments,
    endpoints,
    open_session,
    session_config,
)

__all__ = [
    "DUMP_SIGNAL",
    "MEMBERS_ENV",
    "MEMBERS_FILE_ENV",
    "MEMBER_ENV",
    "Bus",
    "Incoming",
    "Lockstep",
    "Loop",
    "MemoryBus",
    "PhaseInbox",
    "Publisher",
    "Query",
    "Realtime",
    "Sample",
    "Service",
    "TimePolicy",
    "ZenohBus",
    "add_arguments",
    "check_readable",
    "dump_stacks_on_signal",
    "endpoints",
    "load_scenario",
    "open_service",
    "open_session",
    "scenario_or_report",
    "serve",
    "service_parser",
    "session_config",
    "settle_heap",
    "stop_on_signals",
    "time_policy",
]
