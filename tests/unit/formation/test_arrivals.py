"""The receiver's side of the epoch close: explicit, implicit, and announced closes."""

from __future__ import annotations

from formation.arrivals import Arrivals
from formation.codec import CLOSE_FOLLOWS, attachment
from formation.messages import Delivered, EpochClose


def close(epoch: int, delivered: list[tuple[int, int, int]], lost: list[int]) -> EpochClose:
    return EpochClose(
        run_id="r", sender="netem", seq=0, epoch=epoch, stamp_ns=0, receiver=3, phase="state",
        delivered=[Delivered(source=s, seq=q, sent_epoch=e) for s, q, e in delivered], lost=lost,
    )  # fmt: skip


def test_complete_without_a_close_once_every_sender_is_here() -> None:
    a = Arrivals()
    a.packet(4, 1, 40, attachment(4, 40, 1))
    assert a.delivered(4, [1, 2]) is None
    a.packet(4, 2, 41, attachment(4, 41, 2))
    assert a.delivered(4, [1, 2]) == [(1, 40, 4), (2, 41, 4)]


def test_an_announced_close_is_waited_for_and_lists_the_epoch() -> None:
    a = Arrivals()
    a.packet(4, 1, 40, attachment(4, 40, 1, CLOSE_FOLLOWS))
    a.packet(4, 2, 41, attachment(4, 41, 2))
    assert a.delivered(4, [1, 2]) is None  # every sender is here, yet a close follows
    assert a.close(close(4, [(1, 40, 4), (2, 41, 4), (2, 30, 3)], []), current=4)
    assert a.delivered(4, [1, 2]) is None  # the delayed packet it lists is not here yet
    a.packet(3, 2, 30, attachment(3, 30, 2))
    assert a.delivered(4, [1, 2]) == [(1, 40, 4), (2, 41, 4), (2, 30, 3)]


def test_a_close_with_a_loss_completes_the_epoch_and_old_ones_are_dropped() -> None:
    a = Arrivals()
    a.packet(5, 1, 50, None)
    assert a.close(close(5, [(1, 50, 5)], lost=[2]), current=5)
    assert a.delivered(5, [1, 2]) == [(1, 50, 5)]
    a.forget(5)
    assert a.delivered(5, [1, 2]) is None
    assert not a.close(close(5, [], lost=[1, 2]), current=6)  # an epoch already done
