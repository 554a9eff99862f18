"""A compose file's services as local processes, each on its own loopback address.

What ``docker compose up`` would start, without Docker: the file is parsed (it
is the only source of what runs), each service's ``command`` runs as a real
process (``python`` is this interpreter), service ``k`` in file order gets the
address ``127.A.B.(k + 2)`` of a /24 inside 127.0.0.0/8 (all loopback on
Linux), and the service names in Zenoh endpoints resolve to those addresses as
the compose network's DNS would. A client's connection is bound to its own
address (``#bind=``), so the router sees every service from a different host.
Bind mounts, secrets and configs map container paths back to host files.
``depends_on`` is honoured: ``service_healthy`` waits until the dependency's
listen endpoints accept connections, ``service_completed_successfully`` until
it has exited with 0. Every process is ended by PID (TERM, then KILL after its
``stop_grace_period``) by :meth:`LoopbackDeployment.down`, also on error.

A test harness, not part of the product (it is not in the wheel): used by the compose
tests and ``bench/bench_deploy.py`` (``python -m bench`` from the checkout). ``up(late=...)``
starts some services that many seconds after the others, as an engine might.
"""

from __future__ import annotations

import os
import random
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from types import TracebackType
from typing import Any

import yaml

from formation.errors import RuntimeFailure, TestbedError
from testbed.runtime.processes import Child

_VAR = re.compile(r"\$(?:(\$)|\{(\w+)(?:(:?-)([^}]*))?\}|(\w+))")
ENDPOINT = re.compile(r"\b(tcp|tls|udp|quic)/([A-Za-z0-9_.\-]+):(\d+)")
DEFAULT_GRACE_S = 10.0  # docker's default stop timeout [s]
SECRETS = PurePosixPath("/run/secrets")


class ComposeFileError(TestbedError):
    """A compose file this runner cannot map onto local processes."""

    def __init__(self, path: Path | str, where: str, problem: str) -> None:
        self.path, self.where, self.problem = path, where, problem
        super().__init__(f"{path}: {where}: {problem}")


def interpolate(value: str, env: Mapping[str, str]) -> str:
    """Compose's variable substitution: ``${VAR}``, ``${VAR:-default}``, ``${VAR-default}``, ``$$``."""

    def sub(m: re.Match[str]) -> str:
        if m.group(1):
            return "$"
        name = m.group(2) or m.group(5)
        op, default = m.group(3), m.group(4) or ""
        if op == ":-":
            return env.get(name) or default
        if op == "-":
            return env.get(name, default)
        return env.get(name, "")

    return _VAR.sub(sub, value)


def parse_duration_s(text: str | int | float | None, default: float = DEFAULT_GRACE_S) -> float:
    """``"2m"``, ``"1m30s"``, ``"500ms"``, ``"10s"`` → seconds."""
    if text is None:
        return default
    if isinstance(text, (int, float)):
        return float(text)
    units = {"h": 3600.0, "m": 60.0, "s": 1.0, "ms": 1e-3, "us": 1e-6}
    total, pos = 0.0, 0
    for m in re.finditer(r"(\d+(?:\.\d+)?)(ms|us|h|m|s)", text):
        if m.start() != pos:
            break
        total += float(m.group(1)) * units[m.group(2)]
        pos = m.end()
    if pos != len(text) or not text:
        raise ComposeFileError(
            "compose file", "stop_grace_period", f"cannot read duration {text!r}"
        )
    return total


@dataclass
class LocalService:
    """One service of the file, translated to this machine."""

    name: str
    address: str
    argv: list[str]
    env: dict[str, str]
    depends_on: dict[str, str]  # dependency → condition
    grace_s: float
    listen: list[tuple[str, int]] = field(default_factory=list)  # (address, port)
    child: Child | None = None


class LoopbackDeployment:
    """The services of ``compose_file`` as processes on ``127.A.B.N``; use as a context manager."""

    def __init__(
        self,
        compose_file: Path,
        log_dir: Path,
        env: Mapping[str, str] | None = None,
        subnet: tuple[int, int] | None = None,
        max_grace_s: float = 60.0,
    ) -> None:
        self.file = Path(compose_file)
        self.project_dir = self.file.resolve().parent
        self.log_dir = Path(log_dir)
        self.env = dict(env or {})
        self.max_grace_s = max_grace_s
        self.doc: dict[str, Any] = yaml.safe_load(self.file.read_text())
        names = list(self.doc.get("services") or {})
        if not names:
            raise ComposeFileError(self.file, "services", "no services")
        a, b = subnet or _free_subnet()
        self.host_address = f"127.{a}.{b}.1"  # where the caller's own sessions sit
        self.addresses = {name: f"127.{a}.{b}.{k + 2}" for k, name in enumerate(names)}
        self.services = [self._translate(name) for name in _start_order(self.file, self.doc)]
        self.started: list[LocalService] = []

    # -- translation ----------------------------------------------------------------------
    def _value(self, text: str, mounts: dict[str, Path]) -> str:
        text = interpolate(str(text), self.env)
        text = ENDPOINT.sub(self._resolve, text)
        for target in sorted(mounts, key=len, reverse=True):
            if text == target or text.startswith(target + "/"):
                return str(mounts[target]) + text[len(target) :]
        return text

    def _resolve(self, m: re.Match[str]) -> str:
        proto, host, port = m.groups()
        return f"{proto}/{self.addresses.get(host, host)}:{port}"

    def resolve_endpoint(self, endpoint: str) -> str:
        """An endpoint of the file (``tcp/router:7447``) as it is reached from the caller's host."""
        return ENDPOINT.sub(self._resolve, interpolate(endpoint, self.env))

    def bound(self, endpoint: str, address: str | None = None) -> str:
        """``endpoint`` with the connection's source bound to ``address`` (default: the caller's)."""
        return f"{self.resolve_endpoint(endpoint)}#bind={address or self.host_address}:0"

    def _host_file(self, source: str) -> Path:
        p = Path(interpolate(source, self.env))
        return p if p.is_absolute() else (self.project_dir / p).resolve()

    def _mounts(self, name: str, spec: dict[str, Any]) -> dict[str, Path]:
        mounts: dict[str, Path] = {}
        for vol in spec.get("volumes") or []:
            if isinstance(vol, str):
                parts = interpolate(vol, self.env).split(":")
                if len(parts) < 2:
                    raise ComposeFileError(
                        self.file, f"services.{name}.volumes", f"{vol!r} is not a bind mount"
                    )
                source, target = parts[0], parts[1]
            else:
                source, target = vol.get("source", ""), vol["target"]
            if not (source.startswith((".", "/", "$"))):
                raise ComposeFileError(
                    self.file,
                    f"services.{name}.volumes",
                    f"named volume {source!r} is not supported",
                )
            mounts[target] = self._host_file(source)
        for kind, default_dir in (("secrets", SECRETS), ("configs", PurePosixPath("/"))):
            top = self.doc.get(kind) or {}
            for item in spec.get(kind) or []:
                src = item if isinstance(item, str) else item["source"]
                target = src if isinstance(item, str) else item.get("target", src)
                if src not in top or "file" not in top[src]:
                    raise ComposeFileError(self.file, f"{kind}.{src}", "expected a file: entry")
                mounts[str(default_dir / target)] = self._host_file(top[src]["file"])
        return mounts

    def _translate(self, name: str) -> LocalService:
        spec = self.doc["services"][name]
        mounts = self._mounts(name, spec)
        command = spec.get("command")
        if not isinstance(command, list) or not command:
            raise ComposeFileError(self.file, f"services.{name}.command", "expected a list")
        argv = [self._value(str(a), mounts) for a in command]
        if argv[0] in ("python", "python3"):
            argv[0] = sys.executable
        raw_env = spec.get("environment") or {}
        if isinstance(raw_env, list):
            raw_env = dict(item.split("=", 1) for item in raw_env)
        env = {k: self._value(str(v), mounts) for k, v in raw_env.items()}
        address = self.addresses[name]
        if "ZENOH_CONNECT" in env:  # every connection leaves from the service's own host address
            env["ZENOH_CONNECT"] = ",".join(
                f"{e}#bind={address}:0" for e in env["ZENOH_CONNECT"].split(",") if e
            )
        listen_values = [env.get("ZENOH_LISTEN", "")]
        listen_values += [argv[k + 1] for k, a in enumerate(argv[:-1]) if a == "--listen"]
        listen = [
            (m.group(2), int(m.group(3))) for v in listen_values for m in ENDPOINT.finditer(v)
        ]
        depends = spec.get("depends_on") or {}
        if isinstance(depends, list):
            depends = {d: {"condition": "service_started"} for d in depends}
        return LocalService(
            name=name,
            address=address,
            argv=argv,
            env=env,
            depends_on={
                d: (c or {}).get("condition", "service_started") for d, c in depends.items()
            },
            grace_s=min(parse_duration_s(spec.get("stop_grace_period")), self.max_grace_s),
            listen=listen,
        )

    # -- running ----------------------------------------------------------------------------
    def service(self, name: str) -> LocalService:
        for s in self.services:
            if s.name == name:
                return s
        raise KeyError(name)

    def up(self, timeout_s: float = 30.0, late: Mapping[str, float] | None = None) -> None:
        """Start every service in dependency order, waiting on the conditions of ``depends_on``.

        ``late``: services started that many seconds after the others are up; nothing waits
        for them (a dependency on one is skipped), as when an engine ignores the conditions.
        """
        self.log_dir.mkdir(parents=True, exist_ok=True)
        late = dict(late or {})
        for svc in self.services:
            if svc.name in late:
                continue
            for dep, condition in svc.depends_on.items():
                if dep not in late:
                    self._wait_condition(self.service(dep), condition, timeout_s)
            self._start(svc)
        t0 = time.monotonic()
        for name, delay_s in sorted(late.items(), key=lambda item: item[1]):
            while time.monotonic() - t0 < delay_s:
                self.check()  # a service that gave up early fails the wait at once
                time.sleep(0.05)
            self._start(self.service(name))

    def _start(self, svc: LocalService) -> None:
        base = {k: v for k, v in os.environ.items() if not k.startswith("ZENOH_")}
        log_path = self.log_dir / f"{svc.name}.log"
        with log_path.open("wb") as log:
            proc = subprocess.Popen(
                svc.argv,
                stdout=log,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                env={**base, "PYTHONUNBUFFERED": "1", **svc.env},
                cwd=self.log_dir,
                start_new_session=True,
            )
        svc.child = Child(svc.name, proc, log_path)
        self.started.append(svc)

    def _wait_condition(self, dep: LocalService, condition: str, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while True:
            self.check(dep.name)
            if condition == "service_started" and dep.child is not None:
                return
            if condition == "service_healthy" and dep.child is not None:
                if not dep.listen:
                    raise ComposeFileError(
                        self.file,
                        f"services.{dep.name}",
                        "service_healthy needs a listen endpoint to probe",
                    )
                if all(_accepts(host, port) for host, port in dep.listen):
                    return
            if condition == "service_completed_successfully" and dep.child is not None:
                code = dep.child.proc.poll()
                if code == 0:
                    return
            if time.monotonic() > deadline:
                raise RuntimeFailure(
                    f"timed out after {timeout_s:g} s waiting for {dep.name} ({condition})"
                )
            time.sleep(0.01)

    def check(self, *names: str) -> None:
        """Raise :class:`RuntimeFailure` with the log's tail if one of ``names`` (or any) failed."""
        for svc in self.started:
            if names and svc.name not in names:
                continue
            if svc.child is None:
                continue
            code = svc.child.proc.poll()
            if code not in (None, 0):
                raise RuntimeFailure(
                    f"{svc.name} (pid {svc.child.pid}) exited with code {code}:\n{svc.child.tail()}"
                )

    def wait_exit(self, names: list[str], timeout_s: float) -> dict[str, int]:
        """Wait until every service in ``names`` has exited with 0; fails early on any error."""
        deadline = time.monotonic() + timeout_s
        while True:
            self.check()
            codes = {n: self.service(n).child.proc.poll() for n in names}  # type: ignore[union-attr]
            if all(c == 0 for c in codes.values()):
                return {n: 0 for n in names}
            if time.monotonic() > deadline:
                running = [n for n, c in codes.items() if c is None]
                raise RuntimeFailure(
                    f"timed out after {timeout_s:g} s; still running: {', '.join(running)}"
                )
            time.sleep(0.02)

    def stop(self, name: str) -> int | None:
        """``docker compose stop name``: SIGTERM, then SIGKILL after its grace period; the exit code."""
        svc = self.service(name)
        if svc.child is None:
            return None
        proc = svc.child.proc
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGTERM)
            try:
                proc.wait(svc.grace_s)
            except subprocess.TimeoutExpired:
                os.kill(proc.pid, signal.SIGKILL)
                proc.wait(5.0)
        return proc.returncode

    def down(self) -> dict[str, int | None]:
        """``docker compose down``: stop every started service, dependents first."""
        return {svc.name: self.stop(svc.name) for svc in reversed(self.started)}

    @property
    def pids(self) -> list[int]:
        return [s.child.pid for s in self.started if s.child is not None]

    def __enter__(self) -> LoopbackDeployment:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        for svc in reversed(self.started):  # on error, do not wait out long grace periods
            if exc_type is not None:
                svc.grace_s = min(svc.grace_s, 5.0)
            self.stop(svc.name)


def _start_order(path: Path, doc: dict[str, Any]) -> list[str]:
    """Services in file order, each after its dependencies (a stable topological sort)."""
    services = doc["services"]
    order: list[str] = []
    visiting: set[str] = set()

    def visit(name: str) -> None:
        if name in order:
            return
        if name in visiting:
            raise ComposeFileError(path, f"services.{name}.depends_on", "dependency cycle")
        if name not in services:
            raise ComposeFileError(path, "depends_on", f"no service {name!r}")
        visiting.add(name)
        for dep in services[name].get("depends_on") or []:
            visit(dep)
        visiting.discard(name)
        order.append(name)

    for name in services:
        visit(name)
    return order


def _accepts(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=0.2):
            return True
    except OSError:
        return False


def _free_subnet() -> tuple[int, int]:
    """A random ``127.A.B.0/24`` (A, B in 1..254): concurrent runs on one machine do not collide."""
    rng = random.SystemRandom()
    return rng.randint(1, 254), rng.randint(1, 254)


__all__ = [
    "ComposeFileError",
    "LocalService",
    "LoopbackDeployment",
    "interpolate",
    "parse_duration_s",
]
