"""netem's ``netem/config`` queryable: a run's link models and capacity queues, shown or
changed from the next epoch (``formation netem``), each change recorded as a
:class:`LinkChange`."""

from __future__ import annotations

import json
import threading
from typing import Any

from pydantic import TypeAdapter, ValidationError

from formation import keys
from formation.capacity import Capacity
from formation.keys import LEADER_ENDPOINT
from formation.linkmodels import LinkModelSpec
from formation.messages import LinkChange
from netem.proxy.lockstep import LockstepCore
from netem.proxy.progress import Progress
from netem.proxy.routes import LinkClass, Links
from shell import Query, Service

_SPECS: TypeAdapter[list[LinkModelSpec]] = TypeAdapter(list[LinkModelSpec])


def _first_error(exc: Exception) -> str:
    """A refused change in one line: pydantic's first error as ``field = value; why``."""
    if isinstance(exc, ValidationError):
        err = exc.errors()[0]
        where = ".".join(str(p) for p in err["loc"])
        return f"{where} = {err.get('input')!r}; {err['msg']}"
    return str(exc)


def link_class(src: int, dst: int) -> LinkClass:
    """The class of the directed link ``src → dst`` (0 is the leader's endpoint)."""
    if dst == LEADER_ENDPOINT:
        return "report"
    return "estimate" if src == LEADER_ENDPOINT else "formation"


class LinkConfig:
    """Answers ``netem/config`` under netem's lock (its packets' handler shares it)."""

    def __init__(
        self,
        service: Service,
        links: Links,
        progress: Progress,
        lockstep: LockstepCore,
        lock: threading.Lock,
    ) -> None:
        self.service, self.run_id = service, service.run_id
        self.links, self.progress, self.lockstep, self.lock = links, progress, lockstep, lock

    def on_query(self, query: Query) -> None:
        try:
            request = json.loads(query.payload.to_bytes()) if query.payload else {"op": "show"}
            with self.lock:
                answer = self.answer(request)
            query.reply(query.key_expr, json.dumps(answer).encode())
        except Exception as exc:
            query.reply(query.key_expr, json.dumps({"ok": False, "error": str(exc)}).encode())

    def answer(self, request: dict[str, Any]) -> dict[str, Any]:
        """``op`` show (every link's models), set (a link's models) or capacity (a queue's)."""
        op = request.get("op", "show")
        if op == "show":
            air, epoch = self.links.air, self.progress.epoch_seen
            return {
                "ok": True,
                "epoch": self.progress.epoch_seen,
                "links": [
                    {
                        "link": f"{s}->{d}",
                        "class": c,
                        "models": [m.model_dump(by_alias=True) for m in lm.specs],
                    }
                    for (c, s, d), lm in sorted(self.links.models.items())
                ],
                "air": None if air is None else air.at(epoch + 1)[0].model_dump(exclude_none=True),
            }
        if op == "capacity":
            return self._capacity(request)
        if op == "air":
            return self._air(request)
        if op != "set":
            return {"ok": False, "error": f"op {op!r}: expected show, set, capacity or air"}
        link = str(request.get("link", ""))
        try:
            src_text, dst_text = link.split("->")
            src, dst = int(src_text), int(dst_text)
        except ValueError:
            return {
                "ok": False,
                "error": f"link {link!r}: expected SRC->DST, e.g. 1->2 (0 is the leader)",
            }
        cls = link_class(src, dst)
        if (cls, src, dst) not in self.links.models:
            return {"ok": False, "error": f"link {link!r}: no such link in the scenario"}
        try:
            specs = _SPECS.validate_python(request.get("models", []))
        except ValidationError as exc:
            err = exc.errors()[0]
            where = ".".join(str(p) for p in err["loc"])
            return {"ok": False, "error": f"models.{where} = {err.get('input')!r}; {err['msg']}"}
        from_epoch = self.progress.epoch_seen + 1
        self.links.models[(cls, src, dst)].replace(specs, from_epoch)
        self.lockstep.models_changed()
        key = keys.netem_change(self.run_id)
        change = LinkChange(
            **self.service.header(key, from_epoch),
            source=src,
            target=dst,
            link_class=cls,
            models=[s.model_dump(by_alias=True) for s in specs],
            from_epoch=from_epoch,
        )
        self.service.publish(key, change)
        return {"ok": True, "link": link, "class": cls, "from_epoch": from_epoch}

    def _air(self, request: dict[str, Any]) -> dict[str, Any]:
        """The shared air's new parameters (``formation netem set medium:air rate_mbps=12``),
        from the next epoch; recorded as a change of every link on it."""
        air = self.links.air
        if air is None:
            return {"ok": False, "error": "the scenario has no shared air; add [network.air]"}
        update = request.get("air", {})
        if not isinstance(update, dict) or not update:
            return {"ok": False, "error": "expected NAME=VALUE ..., e.g. rate_mbps=12"}
        from_epoch = self.progress.epoch_seen + 1
        try:
            now = air.change(update, from_epoch)
        except (ValueError, ValidationError) as exc:
            return {"ok": False, "error": _first_error(exc)}
        key = keys.netem_change(self.run_id)
        params = {"model": "air", **now.model_dump(exclude_none=True)}
        params.pop("kind", None)
        for cls, src, dst in sorted(self.links.models):
            if not air.carries((src, dst)):
                continue
            change = LinkChange(
                **self.service.header(key, from_epoch),
                source=src,
                target=dst,
                link_class=cls,
                models=[params],
                from_epoch=from_epoch,
            )
            self.service.publish(key, change)
        return {"ok": True, "air": params, "from_epoch": from_epoch}

    def _capacity(self, request: dict[str, Any]) -> dict[str, Any]:
        """A queue's new parameters (``formation netem set 3->0 rate rate_bps=64000``), from
        the next epoch; recorded as a :class:`LinkChange` of each link it serves."""
        queues = self.links.capacity
        if queues is None:
            return {
                "ok": False,
                "error": "the scenario has no capacity queues; add [[network.capacity]] to "
                "change them while running",
            }
        try:
            capacity = Capacity.model_validate(request.get("queue", {}))
        except ValidationError as exc:
            err = exc.errors()[0]
            where = ".".join(str(p) for p in err["loc"])
            return {"ok": False, "error": f"rate.{where} = {err.get('input')!r}; {err['msg']}"}
        from_epoch = self.progress.epoch_seen + 1
        try:
            served = queues.change(capacity, from_epoch)
        except ValueError as exc:
            return {"ok": False, "error": str(exc)}
        self.lockstep.models_changed()  # its links' decisions are taken again
        key = keys.netem_change(self.run_id)
        params = capacity.model_dump(
            exclude_none=True, exclude={"scope", "link", "agent", "medium", "links"}
        )
        for src, dst in served:
            cls = link_class(src, dst)
            change = LinkChange(
                **self.service.header(key, from_epoch),
                source=src,
                target=dst,
                link_class=cls,
                models=[{"model": "rate", "queue": capacity.name, **params}],
                from_epoch=from_epoch,
            )
            self.service.publish(key, change)
        return {"ok": True, "queue": capacity.name, "links": len(served), "from_epoch": from_epoch}
