"""The 802.11 PHYs the air model knows: their timing, their rates, a frame's airtime.

Three PHYs of IEEE Std 802.11-2016, each at 20 MHz (22 MHz for DSSS) with its standard
timing (docs/model.md §11):

- ``ofdm``: Clause 17 (802.11a, 5 GHz). aSlotTime 9 µs, aSIFSTime 16 µs, aCWmin 15,
  aCWmax 1023, aCCATime < 4 µs, preamble 16 µs and SIGNAL 4 µs (17.4.4, PHY characteristics);
  TXTIME = 20 µs + 4 µs · ceil((16 + 8 L + 6) / N_DBPS), N_DBPS = 4 · rate in Mb/s
  (17.4.3, TXTIME, eq. 17-29).
- ``erp_ofdm``: Clause 18 (802.11g ERP-OFDM, 2.4 GHz, short slot): the same symbols with
  aSIFSTime 10 µs and a 6 µs signal extension after every frame (18.3.2.4, 18.4.4).
- ``dsss``: Clauses 15 and 16 (802.11b, long preamble): aSlotTime 20 µs, aSIFSTime 10 µs,
  aCWmin 31, aCWmax 1023, aCCATime ≤ 15 µs; PLCP preamble 144 µs and header 48 µs at
  1 Mb/s; TXTIME = 192 µs + ceil(8 L / rate) µs (16.3.4, TXTIME).

DIFS = SIFS + 2 slots and EIFS = SIFS + DIFS + an ACK at the lowest basic rate
(10.3.2.3.5, 10.3.2.3.7); ACKTimeout = SIFS + slot + aRxPHYStartDelay (25 µs for OFDM, 192 µs for DSSS;
10.3.2.9). An ACK is 14 octets (9.3.1.4); a data frame's MAC header and FCS
28 (24 + 4, 9.3.2.1). A control response goes at the highest basic rate not above the data
rate (10.6.6.5): 6, 12, 24 Mb/s for OFDM, 1 and 2 for DSSS.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

PhyName = Literal["ofdm", "erp_ofdm", "dsss"]

US = 1_000  # [ns] in a µs
ACK_BYTES = 14  # [B] frame control, duration, RA, FCS
MAC_OVERHEAD_BYTES = 28  # [B] a data frame's MAC header (24) and FCS (4)


@dataclass(frozen=True)
class Phy:
    """One PHY's timing and rates. Times in integer nanoseconds, rates in kb/s."""

    name: PhyName
    slot_ns: int
    sifs_ns: int
    cw_min: int
    cw_max: int
    cca_ns: int  # aCCATime: how long a start takes to turn the medium busy
    preamble_ns: int  # PLCP preamble and header
    rx_start_delay_ns: int  # aRxPHYStartDelay
    signal_extension_ns: int
    rates_kbps: tuple[int, ...]
    basic_kbps: tuple[int, ...]
    # SINR [dB] a frame needs at each rate (docs/model.md §11: the standard's minimum
    # sensitivities less its noise figure, 10 dB, and implementation margin, 5 dB)
    sinr_db: tuple[float, ...]
    bandwidth_hz: float

    @property
    def difs_ns(self) -> int:
        return self.sifs_ns + 2 * self.slot_ns

    @property
    def ofdm(self) -> bool:
        return self.name != "dsss"

    @property
    def header_window_ns(self) -> tuple[int, int]:
        """The PHY header's bits on the air, from the frame's start [ns]: OFDM's SIGNAL field
        (17.3.2); DSSS's whole long PLCP preamble and header (16.2.2), as ns-3 counts them."""
        return (16 * US, 20 * US) if self.ofdm else (0, self.preamble_ns)

    @property
    def header_kbps(self) -> int:
        """The rate of the PHY header: 6 Mb/s (OFDM) or 1 Mb/s (DSSS, long preamble)."""
        return 6000 if self.ofdm else 1000

    def rate_kbps(self, rate_mbps: float) -> int:
        """The rate in kb/s; a ``ValueError`` naming the PHY's rates when it has no such rate."""
        kbps = round(rate_mbps * 1000)
        if kbps not in self.rates_kbps or not math.isclose(kbps, rate_mbps * 1000):
            shown = ", ".join(f"{r / 1000:g}" for r in self.rates_kbps)
            raise ValueError(f"{self.name} has no rate {rate_mbps:g} Mb/s; expected one of {shown}")
        return kbps

    def airtime_ns(self, frame_bytes: int, rate_kbps: int) -> int:
        """TXTIME of a PSDU of ``frame_bytes`` octets (MAC header and FCS included) [ns]."""
        if self.ofdm:
            bits_per_symbol = rate_kbps * 4 // 1000  # N_DBPS
            symbols = -(-(16 + 8 * frame_bytes + 6) // bits_per_symbol)
            return self.preamble_ns + 4 * US * symbols + self.signal_extension_ns
        return self.preamble_ns + -(-(8 * frame_bytes * 1000) // rate_kbps) * US

    def control_rate_kbps(self, data_kbps: int) -> int:
        """The rate of the ACK to a frame sent at ``data_kbps``."""
        below = [r for r in self.basic_kbps if r <= data_kbps]
        return max(below) if below else min(self.basic_kbps)

    def ack_ns(self, data_kbps: int) -> int:
        return self.airtime_ns(ACK_BYTES, self.control_rate_kbps(data_kbps))

    def eifs_ns(self) -> int:
        return self.sifs_ns + self.difs_ns + self.airtime_ns(ACK_BYTES, min(self.basic_kbps))

    def ack_timeout_ns(self) -> int:
        return self.sifs_ns + self.slot_ns + self.rx_start_delay_ns

    def sinr_threshold_db(self, rate_kbps: int) -> float:
        return self.sinr_db[self.rates_kbps.index(rate_kbps)]


_OFDM_RATES = (6000, 9000, 12000, 18000, 24000, 36000, 48000, 54000)
# Table 17-18's minimum sensitivities, -82 ... -65 dBm, less -174 dBm/Hz + 73 dB(20 MHz) + 15 dB
_OFDM_SINR = (4.0, 5.0, 7.0, 9.0, 12.0, 16.0, 20.0, 21.0)

_OFDM = Phy(
    name="ofdm",
    slot_ns=9 * US,
    sifs_ns=16 * US,
    cw_min=15,
    cw_max=1023,
    cca_ns=4 * US,
    preamble_ns=20 * US,
    rx_start_delay_ns=25 * US,
    signal_extension_ns=0,
    rates_kbps=_OFDM_RATES,
    basic_kbps=(6000, 12000, 24000),
    sinr_db=_OFDM_SINR,
    bandwidth_hz=20e6,
)

PHYS: dict[str, Phy] = {
    "ofdm": _OFDM,
    # ERP-OFDM (Clause 18, 802.11g): OFDM with a shorter SIFS and a signal extension
    "erp_ofdm": replace(_OFDM, name="erp_ofdm", sifs_ns=10 * US, signal_extension_ns=6 * US),
    # 2 and 11 Mb/s from the minimum sensitivities of 15.4.8.2 (-80 dBm) and 16.3.8.2
    # (-76 dBm) as for OFDM at 22 MHz; 1 and 5.5 Mb/s 3 dB below them [choice]
    "dsss": Phy(
        name="dsss",
        slot_ns=20 * US,
        sifs_ns=10 * US,
        cw_min=31,
        cw_max=1023,
        cca_ns=15 * US,
        preamble_ns=192 * US,
        rx_start_delay_ns=192 * US,
        signal_extension_ns=0,
        rates_kbps=(1000, 2000, 5500, 11000),
        basic_kbps=(1000, 2000),
        sinr_db=(2.6, 5.6, 6.6, 9.6),
        bandwidth_hz=22e6,
    ),
}

__all__ = ["ACK_BYTES", "MAC_OVERHEAD_BYTES", "PHYS", "US", "Phy", "PhyName"]
