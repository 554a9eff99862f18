"""The services' shell: a Zenoh session and what every service does with it (docs/architecture.md "Layers").

Between the vocabulary (:mod:`formation`, no Zenoh) and the services.
"""

from shell.clock import fetch_clock
from shell.service import Incoming, Service, drain_last, settle_heap
from shell.serving import load_scenario, serve, service_parser
from shell.stack_dump import DUMP_SIGNAL, dump_stacks_on_signal
from shell.zenoh_config import (
    add_arguments,
    endpoints,
    open_session,
    open_with_retry,
    session_config,
)

__all__ = [
    "DUMP_SIGNAL",
    "Incoming",
    "Service",
    "add_arguments",
    "drain_last",
    "dump_stacks_on_signal",
    "endpoints",
    "fetch_clock",
    "load_scenario",
    "open_session",
    "open_with_retry",
    "serve",
    "service_parser",
    "session_config",
    "settle_heap",
]
