"""The shared air as the scenario names it: ``[network.air]`` (netem: ``netem.links.air_network``).

The links a scenario puts on the air share one 802.11 channel (docs/model.md §11): in each
phase of an epoch every packet their loss models (and capacity queues) passed becomes a frame
that contends for the channel with the phase's others, from its sender's true position. Which
links: ``links = "formation"`` (the states), ``"control"`` (reports and estimates, the
leader's end at ``network.access_point``) or ``"all"``. A state goes to its out-neighbours as
one broadcast (``states = "broadcast"``, no ACK, no retry) or one unicast per link
(``"unicast"``); reports and estimates are unicast. Each sender's first frame of a phase is
ready at a keyed offset ``U[0, start_spread_us)`` after the phase's start (the agents' timers
are not in step). Payloads are the messages' nominal encoded sizes
(``formation.wire_size``), or ``payload_bytes`` for all.

When the reports take the air: in a phase of their own after the states'
(``reports = "after_states"``), or in the states' contention period (``"with_states"``: each
agent's report is ready beside its state, at its start offset, so the two contend; the
estimates follow in their own phase). With ``links = "all"`` the reports and estimates share
the states' channel (``control_channel = "shared"``) or have a second channel of their own
with the same radio (``"own"``): their own contention, which no state frame enters.

Every strategy's agents report and take estimates each epoch (the estimate carries
``v_ref``). ``estimation_traffic = "when_used"`` keeps that traffic off the air for a run
whose strategy never reads the leader's estimates (``zero``, ``hold``, ``drop``): its reports
and estimates go as on a link of their own, lossless, as with ``links = "formation"``, so
the strategies that use the estimates pay for their traffic and the others do not.

The radio's parameters left unset take the model's defaults (``netem.links.wifi.AirConfig``:
IEEE 802.11-2016 and ns-3.44), so the defaults live in one place.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

# The data rates of each PHY [Mb/s] (802.11-2016 Clauses 15–18); netem's model has the same
# table, held equal to this by a test.
RATES_MBPS: dict[str, tuple[float, ...]] = {
    "ofdm": (6, 9, 12, 18, 24, 36, 48, 54),
    "erp_ofdm": (6, 9, 12, 18, 24, 36, 48, 54),
    "dsss": (1, 2, 5.5, 11),
}
# the strategies that never read the leader's estimates (docs/model.md §6)
WITHOUT_ESTIMATES = ("zero", "hold", "drop")
AIR_QUEUE = "air"  # the air's name in netem's decision records (their ``queue``)
# why a packet on the air was lost (netem.links.wifi.Cause, lower case), a drop's ``model``
AIR_CAUSES = ("collision", "below_sensitivity", "retry_limit", "late")
RADIO_FIELDS = (
    "phy",
    "rate_mbps",
    "tx_power_dbm",
    "path_loss_exponent",
    "reference_loss_db",
    "reference_distance_m",
    "shadowing_sigma_db",
    "noise_figure_db",
    "rx_sensitivity_dbm",
    "preamble_detection_dbm",
    "preamble_detection_snr_db",
    "energy_detection_dbm",
    "cca_sensitivity_dbm",
    "sinr_threshold_db",
    "retry_limit",
    "cw_min",
    "cw_max",
)


class Air(BaseModel):
    """One shared 802.11 channel: the links on it, how states go, and the radio."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    kind: Literal["air"] = "air"
    links: Literal["formation", "control", "all"] = "formation"
    states: Literal["broadcast", "unicast"] = "broadcast"
    payload_bytes: int | None = Field(None, ge=1)  # [B] None: each message's nominal size
    start_spread_us: float = Field(10_000.0, ge=0.0)  # [µs] the senders' start offsets' range
    reports: Literal["after_states", "with_states"] = "after_states"
    control_channel: Literal["shared", "own"] = "shared"
    estimation_traffic: Literal["always", "when_used"] = "always"
    # the radio: None takes the model's default
    phy: Literal["ofdm", "erp_ofdm", "dsss"] = "ofdm"
    rate_mbps: float = 6.0
    tx_power_dbm: float | None = None
    path_loss_exponent: float | None = Field(None, gt=0.0)
    reference_loss_db: float | None = None  # [dB] at reference_distance_m
    reference_distance_m: float | None = Field(None, gt=0.0)
    shadowing_sigma_db: float | None = Field(None, ge=0.0)
    noise_figure_db: float | None = Field(None, ge=0.0)
    rx_sensitivity_dbm: float | None = None
    preamble_detection_dbm: float | None = None
    preamble_detection_snr_db: float | None = None
    energy_detection_dbm: float | None = None
    cca_sensitivity_dbm: float | None = None
    sinr_threshold_db: float | None = None
    retry_limit: int | None = Field(None, ge=1)
    cw_min: int | None = Field(None, ge=1)
    cw_max: int | None = Field(None, ge=1)

    def radio(self) -> dict[str, object]:
        """The radio's parameters set here, for the model's ``AirConfig``."""
        return {f: getattr(self, f) for f in RADIO_FIELDS if getattr(self, f) is not None}

    @property
    def reports_with_states(self) -> bool:
        """Whether the reports take the air in the states' contention period."""
        return self.reports == "with_states"

    def carries(self, link_class: str, strategy: str | None = None) -> bool:
        """Whether packets of ``link_class`` (formation, report, estimate) take the air in a
        run of ``strategy`` (None: any)."""
        unused = self.estimation_traffic == "when_used" and strategy in WITHOUT_ESTIMATES
        if link_class != "formation" and unused:
            return False
        if self.links == "all":
            return True
        return (link_class == "formation") == (self.links == "formation")


def air_problems(
    air: Air | None,
    access_point: tuple[float, ...] | None,
    mode: str = "lockstep",
    queues: bool = False,
    events: bool = False,
) -> list[tuple[str, object, str]]:
    """The first problem of ``network.air`` as ``(field, value, problem)``; ``[]`` when none;
    ``queues``: the scenario has capacity queues; ``events``: team events."""
    if air is None:
        return []
    if air.reports_with_states:
        # netem decides the states' period before the reports exist: from the team and the
        # report links' models, which queues, events and realtime arrivals would change
        if air.links != "all":
            return [("network.air.reports", air.reports, 'with the states needs links = "all"')]
        why = [
            (mode != "lockstep", "runtime.mode", mode),
            (queues, "network.capacity", "set"),
            (events, "events", "set"),
        ]
        for bad, field, value in why:
            if bad:
                problem = 'the reports with the states (network.air.reports = "with_states") '
                return [(field, value, problem + "run in lockstep, without queues or events")]
    if mode != "lockstep" and queues:
        problem = "the shared air with capacity queues runs in lockstep only"
        return [("runtime.mode", mode, problem)]
    rates = RATES_MBPS[air.phy]
    if not any(math.isclose(air.rate_mbps, r) for r in rates):
        shown = ", ".join(f"{r:g}" for r in rates)
        return [("network.air.rate_mbps", air.rate_mbps, f"{air.phy} has the rates {shown} Mb/s")]
    low, high = air.cw_min, air.cw_max
    if low is not None and high is not None and low > high:
        return [("network.air.cw_min", low, f"above cw_max {high}")]
    if air.links != "formation" and access_point is None:
        return [
            (
                "network.air.links",
                air.links,
                "control links on the air need network.access_point (the leader's radio)",
            )
        ]
    return []


__all__ = [
    "AIR_CAUSES",
    "AIR_QUEUE",
    "RADIO_FIELDS",
    "RATES_MBPS",
    "WITHOUT_ESTIMATES",
    "Air",
    "air_problems",
]
