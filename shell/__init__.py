"""The services' shell: the bus and what every service does on it (docs/architecture.md "Layers").

Between the vocabulary (:mod:`formation`, no Zenoh) and the services. A service talks to
a :class:`Bus`: :class:`ZenohBus` in the product, :class:`MemoryBus` in unit tests; its
node runs one loop under a :class:`TimePolicy`, :class:`Lockstep` or :class:`Realtime`, and
takes its inputs from the policy's :class:`PhaseInbox`.

The names below load on first use (PEP 562): a command whose ``--help`` needs only the Zenoh
flags (``add_arguments``) does not load Zenoh.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from formation.first_use import load_on_first_use

if TYPE_CHECKING:
    from shell.bus import (
        Bus,
        MemoryBus,
        Publisher,
        Query,
        Sample,
        ZenohBus,
    )
    from shell.config_files import check_readable
    from shell.inbox import Columns, PhaseInbox
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

_HOMES = {
    "MEMBER_ENV": "shell.zenoh_config",
    "MEMBERS_ENV": "shell.zenoh_config",
    "MEMBERS_FILE_ENV": "shell.zenoh_config",
    "add_arguments": "shell.zenoh_config",
    "endpoints": "shell.zenoh_config",
    "open_session": "shell.zenoh_config",
    "session_config": "shell.zenoh_config",
    "Bus": "shell.bus",
    "Columns": "shell.inbox",
    "DUMP_SIGNAL": "shell.stack_dump",
    "Incoming": "shell.service",
    "Lockstep": "shell.timing",
    "Loop": "shell.loop",
    "MemoryBus": "shell.bus",
    "PhaseInbox": "shell.inbox",
    "Publisher": "shell.bus",
    "Query": "shell.bus",
    "Realtime": "shell.timing",
    "Sample": "shell.bus",
    "Service": "shell.service",
    "TimePolicy": "shell.timing",
    "ZenohBus": "shell.bus",
    "check_readable": "shell.config_files",
    "dump_stacks_on_signal": "shell.stack_dump",
    "load_scenario": "shell.serving",
    "open_service": "shell.serving",
    "scenario_or_report": "shell.serving",
    "serve": "shell.serving",
    "service_parser": "shell.serving",
    "settle_heap": "shell.service",
    "stop_on_signals": "shell.serving",
    "time_policy": "shell.timing",
}

__getattr__ = load_on_first_use(__name__, _HOMES)


__all__ = [
    "DUMP_SIGNAL",
    "MEMBERS_ENV",
    "MEMBERS_FILE_ENV",
    "MEMBER_ENV",
    "Bus",
    "Columns",
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
