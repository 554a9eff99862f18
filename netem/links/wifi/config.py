"""The parameters of a shared 802.11 channel, with the standard's and ns-3's defaults.

Each default names its source (docs/model.md §11): IEEE Std 802.11-2016 for the MAC and the
PHY, ns-3.44 (``YansWifiPhy``, ``LogDistancePropagationLossModel``,
``ThresholdBasedPreambleDetectionModel``) for the radio, where ns-3 is the reference the model
is checked against.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from netem.links.wifi.phy import MAC_OVERHEAD_BYTES, PHYS, Phy, PhyName


class AirConfig(BaseModel):
    """One channel: its PHY and rate, the radios, the propagation, the MAC's limits."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    phy: PhyName = "ofdm"
    rate_mbps: float = 6.0  # data rate; one of the PHY's
    # propagation, ns-3's defaults: log-distance, exponent 3, 46.6777 dB at 1 m (5.15 GHz)
    tx_power_dbm: float = 16.0206  # ns-3 YansWifiPhy TxPowerStart/TxPowerEnd
    path_loss_exponent: float = Field(3.0, gt=0.0)
    reference_loss_db: float = 46.6777  # [dB] at reference_distance_m
    reference_distance_m: float = Field(1.0, gt=0.0)
    shadowing_sigma_db: float = Field(0.0, ge=0.0)  # log-normal shadowing, per pair and epoch
    # receiver
    noise_figure_db: float = Field(7.0, ge=0.0)  # ns-3 RxNoiseFigure
    rx_sensitivity_dbm: float = -101.0  # ns-3 RxSensitivity: weaker frames are not decoded
    # a frame is detected (and locks the receiver) at this power and SNR: 802.11-2016
    # 17.3.10.6 (CCA: an OFDM start at -82 dBm); ns-3's MinimumRssi and Threshold
    preamble_detection_dbm: float = -82.0
    preamble_detection_snr_db: float = 4.0
    energy_detection_dbm: float = -62.0  # 17.3.10.6: any signal 20 dB above -82 dBm; CcaEdThreshold
    # ns-3 holds the medium busy for a frame it does not receive while the sensed energy
    # reaches CcaSensitivity (PhyEntity::GetCcaThreshold), whether its preamble was caught or not
    cca_sensitivity_dbm: float = -82.0
    # a locked frame is decoded by ns-3's chunk-wise error rates ("chunks") or when its SINR
    # over the largest interference reaches sinr_threshold_db ("threshold")
    error_model: Literal["chunks", "threshold"] = "chunks"
    sinr_threshold_db: float | None = None  # None: the PHY's table for the rate
    # MAC
    retry_limit: int = Field(7, ge=1)  # dot11ShortRetryLimit: attempts of a unicast frame
    mac_overhead_bytes: int = Field(MAC_OVERHEAD_BYTES, ge=0)  # [B] header and FCS
    cw_min: int | None = Field(None, ge=1)  # None: the PHY's aCWmin
    cw_max: int | None = Field(None, ge=1)  # None: the PHY's aCWmax

    @model_validator(mode="after")
    def _rate_and_window(self) -> AirConfig:
        self.physical.rate_kbps(self.rate_mbps)  # a ValueError naming the rates
        if self.window[0] > self.window[1]:
            raise ValueError(f"cw_min {self.window[0]} is above cw_max {self.window[1]}")
        return self

    @property
    def physical(self) -> Phy:
        return PHYS[self.phy]

    @property
    def rate_kbps(self) -> int:
        return self.physical.rate_kbps(self.rate_mbps)

    @property
    def window(self) -> tuple[int, int]:
        """(CWmin, CWmax)."""
        phy = self.physical
        return (self.cw_min or phy.cw_min, self.cw_max or phy.cw_max)

    @property
    def sinr_db(self) -> float:
        """The SINR a data frame needs [dB]."""
        if self.sinr_threshold_db is not None:
            return self.sinr_threshold_db
        return self.physical.sinr_threshold_db(self.rate_kbps)

    @property
    def carrier_sense_dbm(self) -> float:
        """The sensed frames' summed power that holds the medium busy [dBm]."""
        return min(self.energy_detection_dbm, self.cca_sensitivity_dbm)

    @property
    def noise_dbm(self) -> float:
        """Thermal noise over the channel and the receiver's noise figure [dBm]."""
        return -174.0 + 10.0 * math.log10(self.physical.bandwidth_hz) + self.noise_figure_db


__all__ = ["AirConfig"]
