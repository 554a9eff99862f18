"""802.11 phases run in ns-3.44, one process for a batch: the reference the air model is held to.

:func:`run_ns3` runs a batch (``python -m testkit.ns3_air`` with a JSON list of phases on
stdin, each from :func:`phase_request`); prints one JSON line
per phase: its receptions, the seconds ns-3 took, the data frames (attempts) and ACKs its PHYs
sent, and the frames its PHYs dropped, by ns-3's reason. With ``--error-rates`` it samples instead
ns-3's default error-rate model (``TableBasedErrorRateModel``) for each OFDM rate at the
32 B and 1,458 B references every 0.05 dB and prints the cubic fits of
``ln(−ln(1 − PER))`` that ``netem/links/wifi/error_rate.py`` holds. Each phase is its own ns-3 simulation:
the agents at their positions, 802.11 ad hoc (no QoS) on ``YansWifiChannelHelper.Default()``
(log-distance, exponent 3, 46.6777 dB at 1 m) with ns-3's default PHY (16.0206 dBm,
RxSensitivity −101 dBm, the preamble-detection model at −82 dBm and 4 dB, CCA energy detection
−62 dBm: the air model's defaults), ``ConstantRateWifiManager`` at the phase's rate for data,
broadcast and ACKs. Frames go straight to the ``WifiNetDevice`` (no IP, no ARP) one second
into the run, after every initial backoff has ended on the idle medium; the device adds
LLC/SNAP (8 B), so a packet of ``payload_bytes − 8`` makes the MSDU the air model is given. A
C++ receive callback logs the time of each delivery, by frame (its first four bytes) and
receiver. Every phase assigns the devices' random streams from 0, so its draws depend on its
seed and run only, not on the phases before it in the batch.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from typing import Any

import numpy as np
import numpy.typing as npt

START_NS = 1_000_000_000  # the phase's start in the ns-3 run
RUN_NS = 2_000_000_000  # how long a phase may last
SATURATED_RUN_NS = 60_000_000_000  # a saturated phase's

CPP = r"""
#include "ns3/core-module.h"
#include "ns3/network-module.h"
#include "ns3/mobility-module.h"
#include "ns3/wifi-module.h"
using namespace ns3;
namespace air {
struct Rx { int64_t t; uint32_t node; uint32_t frame; };
static std::vector<Rx> rx_log;
static uint32_t first_node = 0;
static int64_t data_tx = 0, ack_tx = 0;  // PPDUs sent: data frames (attempts) and ACKs
static std::vector<int64_t> drops(32, 0);  // PhyRxDrop by WifiPhyRxfailureReason

void OnTxBegin(Ptr<const Packet> p, double) { if (p->GetSize() > 14) ++data_tx; else ++ack_tx; }
void OnRxDrop(Ptr<const Packet>, WifiPhyRxfailureReason why) { ++drops[uint32_t(why) % 32]; }

bool OnRx(Ptr<NetDevice> dev, Ptr<const Packet> p, uint16_t, const Address&) {
  uint8_t b[4] = {0, 0, 0, 0};
  p->CopyData(b, 4);
  uint32_t id = b[0] | (b[1] << 8) | (b[2] << 16) | (uint32_t(b[3]) << 24);
  rx_log.push_back({Simulator::Now().GetNanoSeconds(), dev->GetNode()->GetId() - first_node, id});
  return true;
}

void Send(Ptr<NetDevice> dev, uint32_t id, uint32_t size, Address dest) {
  std::vector<uint8_t> b(size < 4 ? 4 : size, 0);
  b[0] = id & 0xff; b[1] = (id >> 8) & 0xff; b[2] = (id >> 16) & 0xff; b[3] = (id >> 24) & 0xff;
  dev->Send(Create<Packet>(b.data(), b.size()), dest, 0x88B5);
}

std::vector<int64_t> RunPhase(const std::vector<double>& x, const std::vector<double>& y,
    const std::vector<int>& sender, const std::vector<int>& receiver,
    const std::vector<int>& size, const std::vector<int64_t>& ready,
    uint32_t seed, uint32_t run, bool dsss, std::string data, std::string control,
    int64_t start, int64_t span, bool saturated) {
  rx_log.clear();
  data_tx = ack_tx = 0;
  std::fill(drops.begin(), drops.end(), 0);
  RngSeedManager::SetSeed(seed);
  RngSeedManager::SetRun(run);
  Config::SetDefault("ns3::WifiRemoteStationManager::NonUnicastMode", StringValue(data));
  // saturated: every frame queued at once waits as long as it takes, retried without limit
  Config::SetDefault("ns3::WifiMacQueue::MaxDelay", TimeValue(saturated ? Seconds(1000) : MilliSeconds(500)));
  Config::SetDefault("ns3::WifiMac::FrameRetryLimit", UintegerValue(saturated ? 65535 : 7));
  Config::SetDefault("ns3::WifiMacQueue::MaxSize", StringValue(saturated ? "100000p" : "500p"));
  NodeContainer nodes;
  nodes.Create(x.size());
  first_node = nodes.Get(0)->GetId();
  Ptr<ListPositionAllocator> at = CreateObject<ListPositionAllocator>();
  for (size_t i = 0; i < x.size(); ++i) at->Add(Vector(x[i], y[i], 0.0));
  MobilityHelper mobility;
  mobility.SetPositionAllocator(at);
  mobility.SetMobilityModel("ns3::ConstantPositionMobilityModel");
  mobility.Install(nodes);
  WifiHelper wifi;
  wifi.SetStandard(dsss ? WIFI_STANDARD_80211b : WIFI_STANDARD_80211a);
  wifi.SetRemoteStationManager("ns3::ConstantRateWifiManager", "DataMode", StringValue(data),
                               "ControlMode", StringValue(control));
  YansWifiChannelHelper channel = YansWifiChannelHelper::Default();
  YansWifiPhyHelper phy;
  phy.SetChannel(channel.Create());
  WifiMacHelper mac;
  mac.SetType("ns3::AdhocWifiMac");
  NetDeviceContainer devices = wifi.Install(phy, mac, nodes);
  // streams from 0 in every phase: its draws depend on its seed and run, not on the batch
  wifi.AssignStreams(devices, 0);
  for (uint32_t i = 0; i < devices.GetN(); ++i) {
    devices.Get(i)->SetReceiveCallback(MakeCallback(&OnRx));
    Ptr<WifiPhy> phy = DynamicCast<WifiNetDevice>(devices.Get(i))->GetPhy();
    phy->TraceConnectWithoutContext("PhyTxBegin", MakeCallback(&OnTxBegin));
    phy->TraceConnectWithoutContext("PhyRxDrop", MakeCallback(&OnRxDrop));
  }
  for (size_t k = 0; k < sender.size(); ++k) {
    Ptr<NetDevice> dev = devices.Get(sender[k]);
    Address dest = receiver[k] < 0 ? dev->GetBroadcast() : devices.Get(receiver[k])->GetAddress();
    Simulator::Schedule(NanoSeconds(start + ready[k]), &Send, dev, uint32_t(k), uint32_t(size[k]), dest);
  }
  Simulator::Stop(NanoSeconds(start + span));
  Simulator::Run();
  Simulator::Destroy();
  std::vector<int64_t> flat;
  flat.push_back(data_tx);
  flat.push_back(ack_tx);
  flat.insert(flat.end(), drops.begin(), drops.end());
  for (const Rx& r : rx_log) { flat.push_back(r.t - start); flat.push_back(r.node); flat.push_back(r.frame); }
  return flat;
}
}
"""

CSR = r"""
#include "ns3/core-module.h"
#include "ns3/wifi-module.h"
using namespace ns3;
namespace csr {
std::vector<double> Sample(uint64_t kbps, const std::vector<double>& snr_db, uint64_t nbits) {
  static Ptr<TableBasedErrorRateModel> m = CreateObject<TableBasedErrorRateModel>();
  WifiMode mode = OfdmPhy::GetOfdmRate(kbps * 1000, 20);
  WifiTxVector tx;
  tx.SetMode(mode);
  tx.SetChannelWidth(20);
  tx.SetPreambleType(WIFI_PREAMBLE_LONG);
  std::vector<double> out;
  for (double s : snr_db)
    out.push_back(m->GetChunkSuccessRate(mode, tx, std::pow(10.0, s / 10.0), nbits, 1,
                                         WIFI_PPDU_FIELD_DATA));
  return out;
}
}
"""
# ns-3.44's WifiPhyRxfailureReason, in its order (wifi-phy-common.h)
DROP_REASONS = (
    "unknown",
    "unsupported_settings",
    "channel_switching",
    "rxing",
    "txing",
    "sleeping",
    "powered_off",
    "truncated_tx",
    "busy_decoding_preamble",
    "preamble_detect_failure",
    "reception_aborted_by_tx",
    "l_sig_failure",
    "ht_sig_failure",
    "sig_a_failure",
    "sig_b_failure",
    "u_sig_failure",
    "eht_sig_failure",
    "preamble_detection_packet_switch",
    "frame_capture_packet_switch",
    "obss_pd_cca_reset",
    "ppdu_too_late",
    "filtered",
    "dmg_header_failure",
    "dmg_allocation_ended",
    "signal_detection_aborted_by_tx",
)
DROPS_AT = 2 + 32  # the reply's counts before its receptions
OFDM_KBPS = (6000, 9000, 12000, 18000, 24000, 36000, 48000, 54000)


def fit_success(
    grid: npt.NDArray[np.float64], success: npt.NDArray[np.float64]
) -> tuple[float, float, list[float]]:
    """(lowest, highest SINR [dB], cubic of ln(−ln success)) fitting ns-3's success rates."""
    from scipy.optimize import least_squares

    fitted = (success < 1.0 - 1e-5) & (success > 1e-9)
    low, high = float(grid[fitted].min()), float(grid[fitted].max())
    # a start in ln(-ln(success)), then least squares on the success rate itself
    start = np.polyfit(grid[fitted], np.log(-np.log(success[fitted])), 3)
    near = (grid >= low - 0.5) & (grid <= high + 0.5)
    x, target = grid[near], success[near]

    def gap(c: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        s = np.exp(-np.exp(np.polyval(c, np.clip(x, low, high))))
        return np.asarray(np.where(x < low, 0.0, np.where(x > high, 1.0, s)) - target)

    cubic = least_squares(gap, start).x
    return low, high, [float(f"{c:.6g}") for c in cubic]


def error_rates() -> None:
    import cppyy
    from ns import ns

    cppyy.cppdef(CSR)
    del ns
    grid = np.round(np.arange(-10.0, 35.0, 0.05), 2)
    for kbps in OFDM_KBPS:
        fits = [
            fit_success(grid, np.array(list(cppyy.gbl.csr.Sample(kbps, grid.tolist(), nbits))))
            for nbits in (32 * 8, 1458 * 8)
        ]
        print(kbps, fits, flush=True)


MODES = {  # (PHY, data rate in Mb/s) -> ns-3's data and control modes
    ("ofdm", 6.0): ("OfdmRate6Mbps", "OfdmRate6Mbps"),
    ("ofdm", 24.0): ("OfdmRate24Mbps", "OfdmRate24Mbps"),
    ("ofdm", 54.0): ("OfdmRate54Mbps", "OfdmRate24Mbps"),
    ("dsss", 1.0): ("DsssRate1Mbps", "DsssRate1Mbps"),
    ("dsss", 11.0): ("DsssRate11Mbps", "DsssRate2Mbps"),
}


def phase_request(
    phy: str,
    rate_mbps: float,
    positions_m: npt.NDArray[np.float64],
    sender: npt.NDArray[np.int64],
    receiver: npt.NDArray[np.int64],
    payload_bytes: npt.NDArray[np.int64],
    ready_ns: npt.NDArray[np.int64],
    seed: int,
    run: int,
    saturated: bool = False,
) -> dict[str, Any]:
    """One phase for ns-3: the agents' positions (n, 2) [m] and the frames, as the air model's.
    ``saturated``: frames wait in ns-3's queue without its 500 ms lifetime or 500 frames'
    room and are retried without limit, and the phase may last 60 s."""
    return {
        "phy": phy,
        "rate_mbps": rate_mbps,
        "x": positions_m[:, 0].tolist(),
        "y": positions_m[:, 1].tolist(),
        "sender": sender.tolist(),
        "receiver": receiver.tolist(),
        "payload_bytes": payload_bytes.tolist(),
        "ready_ns": ready_ns.tolist(),
        "seed": seed,
        "run": run,
        "saturated": saturated,
    }


def run_ns3(batch: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], float]:
    """ns-3's receptions of each phase, and the wall time of its process with the import [s]."""
    started = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "testkit.ns3_air"],
        input=json.dumps(batch),
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        raise RuntimeError(f"ns-3 failed (exit {done.returncode}): {done.stderr[-2000:]}")
    lines = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]
    return lines, time.perf_counter() - started


def arrivals(reply: dict[str, Any], frames: int, n: int) -> npt.NDArray[np.int64]:
    """(frames, n): when each agent first received each frame [ns from the phase's start], −1."""
    arrival = np.full((frames, n), -1, dtype=np.int64)
    for t, node, f in reply["rx"]:
        if arrival[f, node] < 0:
            arrival[f, node] = t
    return arrival


def main() -> None:
    if "--error-rates" in sys.argv:
        error_rates()
        return
    phases = json.load(sys.stdin)
    import cppyy
    from ns import ns  # loads ns-3's libraries into cppyy: 15-70 s, the headers compile

    cppyy.cppdef(CPP)
    air = cppyy.gbl.air
    del ns  # reached through cppyy.gbl from here on
    for p in phases:
        data, control = MODES[(p["phy"], p["rate_mbps"])]
        started = time.process_time()  # CPU: the model beside it is timed so
        flat = air.RunPhase(
            [float(v) for v in p["x"]],
            [float(v) for v in p["y"]],
            p["sender"],
            p["receiver"],
            [max(4, s - 8) for s in p["payload_bytes"]],  # the device adds LLC/SNAP
            p["ready_ns"],
            p["seed"],
            p["run"],
            p["phy"] == "dsss",
            data,
            control,
            START_NS,
            SATURATED_RUN_NS if p.get("saturated") else RUN_NS,
            bool(p.get("saturated")),
        )
        seconds = time.process_time() - started
        values = [int(v) for v in flat]
        (data_tx, ack_tx), drops, values = values[:2], values[2:DROPS_AT], values[DROPS_AT:]
        rx = [values[k : k + 3] for k in range(0, len(values), 3)]
        reasons = {DROP_REASONS[r]: c for r, c in enumerate(drops) if c and r < len(DROP_REASONS)}
        reply = {"rx": rx, "seconds": seconds, "data_tx": data_tx, "ack_tx": ack_tx}
        print(json.dumps(reply | {"drops": reasons}), flush=True)


if __name__ == "__main__":
    main()
