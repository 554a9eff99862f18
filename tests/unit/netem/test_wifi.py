"""The air model of one phase: airtime by the standard's formulas, carrier sense, collisions,
capture, retries and keyed draws (docs/model.md §10)."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from netem.links.wifi import (
    BROADCAST,
    PHYS,
    AirConfig,
    AirError,
    Cause,
    Frames,
    Key,
    PhaseOutcome,
    decide_phase,
)
from netem.links.wifi.error_rate import chunk_success

US = 1000
DEFAULT = AirConfig()  # 802.11a at 6 Mb/s, ns-3's radio: preamble detected to about 51 m


def on_a_line(*x_m: float) -> np.ndarray:
    return np.array([[x, 0.0] for x in x_m])


# -- airtime: hand-computed from the TXTIME formulas ------------------------------------------
@pytest.mark.parametrize(
    ("phy", "frame_bytes", "rate_kbps", "expected_us"),
    [
        # OFDM: 20 + 4 ceil((16 + 8 L + 6) / N_DBPS)
        ("ofdm", 228, 6000, 20 + 4 * 77),  # 1846 bits / 24 = 76.9
        ("ofdm", 1528, 54000, 20 + 4 * 57),  # 12246 / 216 = 56.7
        ("ofdm", 14, 6000, 20 + 4 * 6),  # an ACK: 134 / 24 = 5.6
        ("ofdm", 14, 24000, 20 + 4 * 2),  # 134 / 96 = 1.4
        ("erp_ofdm", 228, 6000, 20 + 4 * 77 + 6),  # the signal extension
        # DSSS, long preamble: 192 + ceil(8 L / rate)
        ("dsss", 1528, 11000, 192 + 1112),  # 12224 / 11 = 1111.3
        ("dsss", 228, 5500, 192 + 332),  # 1824 / 5.5 = 331.6
        ("dsss", 14, 1000, 192 + 112),
    ],
)
def test_airtime_follows_txtime(
    phy: str, frame_bytes: int, rate_kbps: int, expected_us: int
) -> None:
    assert PHYS[phy].airtime_ns(frame_bytes, rate_kbps) == expected_us * US


def test_interframe_spaces_and_control_rates() -> None:
    ofdm, dsss = PHYS["ofdm"], PHYS["dsss"]
    assert (ofdm.difs_ns, ofdm.eifs_ns()) == (34 * US, (16 + 34 + 44) * US)
    assert (dsss.difs_ns, dsss.eifs_ns()) == (50 * US, (10 + 50 + 304) * US)
    assert ofdm.ack_timeout_ns() == (16 + 9 + 25) * US
    assert [ofdm.control_rate_kbps(r) for r in (6000, 9000, 18000, 54000)] == [6000] * 2 + [
        12000,
        24000,
    ]
    assert dsss.control_rate_kbps(11000) == 2000


def test_a_lone_broadcast_arrives_after_its_airtime() -> None:
    out = decide_phase(
        DEFAULT, on_a_line(0, 30), Frames.of(0, BROADCAST, 200, 50 * US), Key(1, 0, 0)
    )
    assert out.at(0, 1) is Cause.DELIVERED
    assert out.first_start_ns[0] == 50 * US + 34 * US  # ready on an idle medium: after DIFS
    assert out.arrival_ns[0, 1] == out.first_start_ns[0] + 328 * US
    assert out.at(0, 0) is Cause.NOT_ADDRESSED


# -- geometry: hidden terminals, carrier sense, capture ----------------------------------------
def test_hidden_senders_collide_at_the_agent_between_them() -> None:
    # 0 and 2 are 80 m apart, below the preamble threshold of each other; 1 hears both, 2's
    # frame 1.3 dB stronger: 0's long frame cannot survive it, and 1, locked onto 0's, misses 2's
    frames = Frames.of([0, 2], BROADCAST, 1000, [0, 100 * US])
    out = decide_phase(DEFAULT, on_a_line(0, 42, 80), frames, Key(1, 0, 0))
    assert out.first_start_ns.tolist() == [34 * US, 134 * US]  # 2 did not sense 0: no deferral
    assert out.at(0, 1) is Cause.COLLISION
    assert out.at(1, 1) is Cause.COLLISION
    assert out.at(0, 2) is Cause.BELOW_SENSITIVITY
    assert out.attempts.tolist() == [1, 1]  # a broadcast is never retried


def first_of_hidden_pair_delivered(offset_us: int, config: AirConfig) -> int:
    """Of 20 keys, how often 1 (at 40 m from each) decodes 0's frame when 2's starts later."""
    frames = Frames.of([0, 2], BROADCAST, 200, [0, offset_us * US])
    outs = [decide_phase(config, on_a_line(0, 40, 80), frames, Key(s, 0, 0)) for s in range(20)]
    return sum(out.at(0, 1) is Cause.DELIVERED for out in outs)


def test_a_frame_survives_an_equal_interferer_by_how_long_they_overlap() -> None:
    # 328 µs frames at 0 dB SINR over the overlap: ns-3's chunk error rates keep the first
    # frame more often the later the second starts; a SINR threshold loses it every time
    late, early = (first_of_hidden_pair_delivered(t, DEFAULT) for t in (300, 20))
    assert late >= 17 and early < late - 4
    threshold = AirConfig(error_model="threshold")
    assert first_of_hidden_pair_delivered(300, threshold) == 0


def test_senders_within_carrier_sense_take_turns() -> None:
    # the same frames with 0 and 2 50 m apart: 2 senses 0's frame and backs off
    frames = Frames.of([0, 2], BROADCAST, 200, [0, 100 * US])
    out = decide_phase(DEFAULT, on_a_line(0, 25, 50), frames, Key(1, 0, 0))
    assert out.at(0, 1) is Cause.DELIVERED and out.at(1, 1) is Cause.DELIVERED
    assert out.first_start_ns[1] >= 34 * US + 328 * US + 34 * US


def test_a_much_stronger_frame_is_captured() -> None:
    # 0 and 2 send at the same instant; 1 is 10 m from 0 and 45 m from 2 (SINR about 20 dB)
    frames = Frames.of([0, 2], BROADCAST, 200, 0)
    out = decide_phase(DEFAULT, on_a_line(0, 10, 55), frames, Key(1, 0, 0))
    assert out.at(0, 1) is Cause.DELIVERED
    assert out.at(1, 1) is Cause.COLLISION
    equal = decide_phase(DEFAULT, on_a_line(0, 27.5, 55), frames, Key(1, 0, 0))
    assert equal.at(0, 1) is Cause.COLLISION and equal.at(1, 1) is Cause.COLLISION


# -- the chunk error model -------------------------------------------------------------------
@pytest.mark.parametrize(
    ("ofdm", "rate_kbps", "snr_db", "nbits", "ns3"),
    [  # ns-3.44's default error-rate models, sampled (python -m testkit.ns3_air --error-rates)
        (True, 6000, 0.0, 256, 0.9656),
        (True, 54000, 17.0, 11664, 0.1204),
        (False, 1000, -6.0, 256, 0.60043),
        (False, 11000, 5.0, 256, 0.86320),
    ],
)
def test_a_chunk_succeeds_as_in_ns3(
    ofdm: bool, rate_kbps: int, snr_db: float, nbits: int, ns3: float
) -> None:
    got = chunk_success(ofdm, rate_kbps, np.array([10 ** (snr_db / 10)]), np.array([nbits]))
    assert got[0] == pytest.approx(ns3, abs=0.033 if ofdm else 1e-4)


@pytest.mark.parametrize("rate_kbps", [6000, 9000, 12000, 18000, 24000, 36000, 48000, 54000])
def test_a_chunk_succeeds_more_at_higher_sinr_and_when_shorter(rate_kbps: int) -> None:
    snr = 10 ** (np.arange(-10.0, 35.0, 0.05) / 10)
    short, long = (chunk_success(True, rate_kbps, snr, np.full(snr.shape, b)) for b in (256, 11664))
    assert (np.diff(short) > -1e-4).all() and (np.diff(long) > -1e-4).all()
    assert (long <= short).all() and short[0] == 0.0 and long[-1] == 1.0


# -- unicast: ACK and retries ------------------------------------------------------------------
def test_an_acknowledged_unicast_is_sent_once() -> None:
    out = decide_phase(DEFAULT, on_a_line(0, 30), Frames.of(0, 1, 200, 0), Key(1, 0, 0))
    assert out.at(0, 1) is Cause.DELIVERED and out.attempts.tolist() == [1]


def test_a_unicast_out_of_reach_is_tried_up_to_the_retry_limit() -> None:
    out = decide_phase(DEFAULT, on_a_line(0, 300), Frames.of(0, 1, 200, 0), Key(1, 0, 0))
    assert out.attempts.tolist() == [DEFAULT.retry_limit]
    assert out.at(0, 1) is Cause.BELOW_SENSITIVITY
    three = decide_phase(
        AirConfig(retry_limit=3), on_a_line(0, 300), Frames.of(0, 1, 200, 0), Key(1, 0, 0)
    )
    assert three.attempts.tolist() == [3]


def test_hidden_unicasts_retry_and_record_the_retry_limit() -> None:
    frames = Frames.of([0, 2], 1, 200, 0)
    once = decide_phase(AirConfig(retry_limit=1), on_a_line(0, 40, 80), frames, Key(1, 0, 0))
    assert once.attempts.tolist() == [1, 1]
    assert once.at(0, 1) is Cause.RETRY_LIMIT and once.at(1, 1) is Cause.RETRY_LIMIT
    retried = decide_phase(DEFAULT, on_a_line(0, 40, 80), frames, Key(1, 0, 0))
    assert (retried.attempts > 1).all()  # the backoffs drawn after the collision differ


def test_a_frame_received_after_the_phase_is_late() -> None:
    frames = Frames.of(0, BROADCAST, 200, 0)
    out = decide_phase(DEFAULT, on_a_line(0, 30), frames, Key(1, 0, 0), phase_end_ns=300 * US)
    assert out.at(0, 1) is Cause.LATE and not out.delivered[0, 1]
    assert out.arrival_ns[0, 1] == (34 + 328) * US


def test_a_frame_received_in_error_makes_the_receiver_wait_eifs() -> None:
    # 3 locks onto 0's 1000 B frame; 2's 200 B, hidden from 0 and 1.3 dB stronger at 3, ruins
    # it: after 0's frame ends (34 + 1396 µs, 2's long over) 3 counts its backoff from EIFS
    positions = np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 0.0], [42.0, 5.0]])
    frames = Frames.of([0, 2, 3], BROADCAST, [1000, 200, 1000], [0, 100 * US, 50 * US])
    out = decide_phase(DEFAULT, positions, frames, Key(1, 0, 0))
    assert out.at(0, 3) is Cause.COLLISION
    waited = out.first_start_ns[2] - (34 + 1396) * US
    slot, eifs = 9 * US, (16 + 34 + 44) * US
    assert waited >= eifs and (waited - eifs) % slot == 0


def test_a_transmission_ends_the_eifs() -> None:
    # as above, 3 with a second frame: its post-backoff after its own first frame counts from
    # DIFS, as after any transmission (ns-3: NotifyTxStartNow), not from the earlier EIFS
    positions = np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 0.0], [42.0, 5.0]])
    frames = Frames.of(
        [0, 2, 3, 3], BROADCAST, [1000, 200, 1000, 200], np.array([0, 100, 50, 60]) * US
    )
    out = decide_phase(DEFAULT, positions, frames, Key(1, 0, 0))
    waited = out.first_start_ns[3] - (out.first_start_ns[2] + 1396 * US)
    slot, difs = 9 * US, 34 * US
    assert waited >= difs and (waited - difs) % slot == 0


def test_a_frame_not_received_holds_the_medium_busy_down_to_the_cca_sensitivity() -> None:
    # 0 and 1, 15 m apart (-66 dBm, under energy detection's -62), start together; 1's 50 B
    # frame ends first and 0's 1000 B frame, which 1 never locked onto, keeps 1 off its
    # second frame until it ends (ns-3's CcaSensitivity, -82 dBm)
    frames = Frames.of([0, 1, 1], BROADCAST, [1000, 50, 50], [0, 0, 1])
    out = decide_phase(DEFAULT, on_a_line(0, 15), frames, Key(1, 0, 0))
    assert out.first_start_ns[:2].tolist() == [34 * US, 34 * US]
    assert out.first_start_ns[2] >= (34 + 1396 + 34) * US
    deaf = AirConfig(cca_sensitivity_dbm=-62.0)
    assert (
        decide_phase(deaf, on_a_line(0, 15), frames, Key(1, 0, 0)).first_start_ns[2]
        < (34 + 1396) * US
    )


def test_a_frame_queued_on_an_idle_medium_that_turns_busy_draws_no_backoff() -> None:
    # 0 takes the air at 34 µs; the others queue theirs at 10 µs, on an idle medium, which
    # turns busy before their DIFS ends: as in ns-3 (without ProactiveBackoff) they draw no
    # backoff and all go DIFS after 0's frame, together
    rng = np.random.default_rng(7)
    ready = np.r_[0, np.full(11, 10 * US)]
    frames = Frames.of(np.arange(12), BROADCAST, 200, ready)
    out = decide_phase(DEFAULT, rng.uniform(0.0, 10.0, (12, 2)), frames, Key(1, 0, 0))
    assert out.first_start_ns.tolist() == [34 * US] + [(34 + 328 + 34) * US] * 11


def test_an_overheard_unicast_holds_its_neighbours_off_until_the_ack_ends() -> None:
    # 2 decodes 0's frame to 1 but cannot hear 1's ACK (75 m): only the NAV keeps it off
    positions = on_a_line(0, 45, -30)
    frames = Frames.of([0, 2], [1, BROADCAST], 200, [0, 50 * US])
    out = decide_phase(DEFAULT, positions, frames, Key(1, 0, 0))
    assert out.at(0, 1) is Cause.DELIVERED and out.attempts[0] == 1
    ack_end = (34 + 328 + 16 + 44) * US
    waited = out.first_start_ns[1] - ack_end
    slot, difs = 9 * US, 34 * US
    assert waited >= difs and (waited - difs) % slot == 0


# -- keyed draws -------------------------------------------------------------------------------
def contention(key: Key, config: AirConfig = DEFAULT) -> PhaseOutcome:
    # agent 0 takes the air first; the others find it busy and draw backoffs
    rng = np.random.default_rng(7)
    positions = rng.uniform(0.0, 10.0, (12, 2))
    ready = np.r_[0, np.full(11, 100 * US)]
    return decide_phase(config, positions, Frames.of(np.arange(12), BROADCAST, 200, ready), key)


def fields(out: PhaseOutcome) -> list[np.ndarray]:
    return [out.delivered, out.arrival_ns, out.cause, out.attempts, out.first_start_ns]


def test_the_same_key_gives_the_same_phase_to_the_bit() -> None:
    a, b = contention(Key(3, 5, 1)), contention(Key(3, 5, 1))
    assert all(np.array_equal(x, y) for x, y in zip(fields(a), fields(b), strict=True))


@pytest.mark.parametrize("other", [Key(4, 5, 1), Key(3, 6, 1), Key(3, 5, 2)])
def test_another_seed_epoch_or_phase_draws_other_backoffs(other: Key) -> None:
    assert not np.array_equal(
        contention(Key(3, 5, 1)).first_start_ns, contention(other).first_start_ns
    )


def test_shadowing_is_keyed_by_the_seed() -> None:
    shadowed = AirConfig(shadowing_sigma_db=8.0)
    positions = on_a_line(0, 48)  # near the preamble threshold: shadowing decides
    outs = [
        decide_phase(shadowed, positions, Frames.of(0, BROADCAST, 200, 0), Key(s, 0, 0))
        for s in range(12)
    ]
    causes = {out.at(0, 1) for out in outs}
    assert causes == {Cause.DELIVERED, Cause.BELOW_SENSITIVITY}
    again = decide_phase(shadowed, positions, Frames.of(0, BROADCAST, 200, 0), Key(5, 0, 0))
    assert again.at(0, 1) is outs[5].at(0, 1)


# -- bad input ---------------------------------------------------------------------------------
def test_a_frame_from_outside_the_team_is_named() -> None:
    with pytest.raises(AirError, match=r"frames.sender\[1\] = 5; expected an agent 0..2"):
        decide_phase(DEFAULT, on_a_line(0, 1, 2), Frames.of([0, 5], BROADCAST, 10, 0), Key(1, 0, 0))
    with pytest.raises(AirError, match=r"frames.receiver\[0\] = 0; expected another agent"):
        decide_phase(DEFAULT, on_a_line(0, 1, 2), Frames.of(0, 0, 10, 0), Key(1, 0, 0))
    with pytest.raises(AirError, match=r"frames.payload_bytes\[0\] = -1; expected ≥ 0"):
        decide_phase(DEFAULT, on_a_line(0, 1, 2), Frames.of(0, 1, -1, 0), Key(1, 0, 0))
    with pytest.raises(AirError, match=r"frames.ready_ns\[0\] = -1; expected ≥ 0"):
        decide_phase(DEFAULT, on_a_line(0, 1, 2), Frames.of(0, 1, 10, -1), Key(1, 0, 0))


def test_a_rate_the_phy_lacks_is_named() -> None:
    with pytest.raises(ValidationError, match="ofdm has no rate 11 Mb/s; expected one of 6, 9"):
        AirConfig(rate_mbps=11.0)
    with pytest.raises(ValidationError, match="cw_min 63 is above cw_max 31"):
        AirConfig(cw_min=63, cw_max=31)
    assert AirConfig(phy="dsss", rate_mbps=11.0).window == (31, 1023)
