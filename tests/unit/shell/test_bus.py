"""The in-memory bus matches key expressions as Zenoh does, and a Service runs on it."""

from __future__ import annotations

from shell import Incoming, MemoryBus, Sample, Service


def test_subscribers_get_what_their_key_expression_matches() -> None:
    bus = MemoryBus()
    got: dict[str, list[tuple[str, bytes, bytes | None]]] = {"one": [], "star": [], "all": []}

    def into(name: str):  # type: ignore[no-untyped-def]
        def on(sample: Sample) -> None:
            att = sample.attachment
            got[name].append(
                (str(sample.key_expr), sample.payload.to_bytes(), att and att.to_bytes())
            )

        return on

    bus.declare_subscriber("r/agent/1/state", into("one"))
    star = bus.declare_subscriber("r/agent/*/state", into("star"))
    bus.declare_subscriber("r/**", into("all"))
    bus.declare_publisher("r/agent/2/state").put(b"x", attachment=b"a")
    bus.put("r/agent/1/state", b"y")
    star.undeclare()
    bus.put("r/agent/3/state", b"z")
    bus.put("elsewhere/agent/1/state", b"no")
    assert got["one"] == [("r/agent/1/state", b"y", None)]
    assert got["star"] == [("r/agent/2/state", b"x", b"a"), ("r/agent/1/state", b"y", None)]
    assert [k for k, _, _ in got["all"]] == [
        "r/agent/2/state",
        "r/agent/1/state",
        "r/agent/3/state",
    ]
    assert bus.puts["r/agent/2/state"] == 1


def test_queries_get_the_good_replies_of_every_matching_queryable() -> None:
    bus = MemoryBus()
    bus.declare_queryable("r/q/*", lambda q: q.reply(q.key_expr, b"first"))
    bus.declare_queryable("r/q/a", lambda q: q.reply_err(b"no"))
    bus.declare_queryable("r/other", lambda q: q.reply(q.key_expr, b"never"))
    assert list(bus.get("r/q/a", b"{}")) == [b"first"]
    asked: list[bytes | None] = []
    bus.declare_queryable("r/echo", lambda q: asked.append(q.payload and q.payload.to_bytes()))
    assert list(bus.get("r/echo")) == [] and asked == [None]


def test_liveliness_tokens_come_and_go_with_history() -> None:
    bus = MemoryBus()
    first = bus.declare_token("r/alive/agent/1")
    seen: list[tuple[str, bool]] = []
    bus.declare_liveliness_subscriber("r/alive/**", lambda key, alive: seen.append((key, alive)))
    second = bus.declare_token("r/alive/leader/0")
    assert list(bus.tokens("r/alive/*/1", 0.1)) == ["r/alive/agent/1"]
    first.undeclare()
    first.undeclare()  # once only
    second.undeclare()
    assert seen == [
        ("r/alive/agent/1", True),
        ("r/alive/leader/0", True),
        ("r/alive/agent/1", False),
        ("r/alive/leader/0", False),
    ]
    assert list(bus.tokens("r/alive/**", 0.1)) == []


def test_a_service_on_the_memory_bus() -> None:
    times = iter(range(100, 1000))
    bus = MemoryBus(clock=lambda: next(times))
    netem = Service(bus, "r", "netem", 0)
    agent = Service(bus, "r", "agent", 1, start_timeout_s=1.0)
    agent.watch_alive()
    netem.announce()
    assert agent.is_alive("netem", 0) and not agent.is_alive("leader", 0)
    assert not agent.run_started(timeout_s=0.0)
    netem.declare_start()
    assert agent.wait_started() and agent.run_started()
    netem.queryable("formation/r/ask", lambda q: q.reply(q.key_expr, b'{"ok": true}'))
    assert agent.ask("formation/r/ask", {"q": 1}) == {"ok": True}
    agent.subscribe("formation/r/in")
    netem.put("formation/r/in", b"payload", b"att")
    assert agent.next_incoming(0) == Incoming("formation/r/in", b"payload", b"att", 100)
    assert netem.sent == {"formation/r/in": 1}
    netem.close()
    assert not agent.is_alive("netem", 0)
    agent.close()
