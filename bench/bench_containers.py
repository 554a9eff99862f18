"""Containers for real: what podman costs against a native run, measured in the same run.

Run ``python -m bench bench_containers`` from the checkout (``make compose-test`` installs
podman first; without podman this says so and returns). Measured:

1. The base image (the Dockerfile's ``FROM``, made locally by ``deploy/podman.sh base`` when
   no registry serves it), cold (under a scratch tag, so the real one stays cached) and cached.
2. The image build, cold (``--no-cache``: every dependency downloaded and installed) and cached
   (only the layers a change touches), and the image's size.
3. ``podman-compose up`` → netem's exit → ``down`` of the unchanged ``compose.yaml`` with the
   loopback override, against the baseline ``formation run`` of the same scenario and seed
   (``scenarios/paper.toml``, seed from the file), each timed end to end as a user runs it.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "deploy" / "podman.sh"
SCENARIO = ROOT / "scenarios" / "paper.toml"
SCRATCH_BASE = "localhost/formation-bench-base:cold"
SCRATCH_IMAGE = "localhost/formation-bench:cold"


def _env() -> dict[str, str] | None:
    """The variables of ``deploy/podman.sh env``; None (and why) when podman is not there."""
    if shutil.which("podman") is None:
        print("podman is not installed: skipped (make compose-test installs it)")
        return None
    out = subprocess.run([str(SCRIPT), "env"], capture_output=True, text=True, check=True)
    env = dict(line.split("=", 1) for line in out.stdout.splitlines())
    if not Path(env["PODMAN_COMPOSE"]).is_file() or not Path(env["CONTAINERS_CONF"]).is_file():
        print("podman-compose or containers.conf missing: skipped (run deploy/podman.sh engine)")
        return None
    return {**os.environ, **env}


def _timed(argv: list[str], env: dict[str, str], cwd: Path = ROOT, timeout_s: float = 900) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout_s)
    if proc.returncode != 0:
        raise RuntimeError(f"{argv} failed:\n{proc.stderr[-2000:]}")
    return time.perf_counter() - t0


def _rmi(name: str, env: dict[str, str]) -> None:
    subprocess.run(["podman", "rmi", "-f", name], env=env, capture_output=True, check=False)


def _size_mb(image: str, env: dict[str, str]) -> float:
    out = subprocess.run(["podman", "image", "inspect", image, "--format", "{{.Size}}"],
                         env=env, capture_output=True, text=True, check=True)  # fmt: skip
    return int(out.stdout.strip()) / 1e6


def _compose_run(env: dict[str, str], tmp: Path) -> tuple[float, float, float]:
    """Seconds of ``up``, of netem's run until its exit, and of ``down``."""
    compose = [env["PODMAN_COMPOSE"], "-f", "compose.yaml", "-f", "deploy/compose.loopback.yaml"]
    run_env = {**env, "FORMATION_KEYS": str(tmp / "keys"), "FORMATION_RUNS": str(tmp / "runs"),
               "RUN_ID": "bench", "FORMATION_UID": str(os.getuid()),
               "FORMATION_GID": str(os.getgid())}  # fmt: skip
    (tmp / "runs").mkdir()
    up = _timed([*compose, "up", "-d"], run_env)
    try:
        run = _timed(["podman", "wait", "formation_netem_1"], run_env, timeout_s=600)
    finally:
        down = _timed([*compose, "down"], run_env, timeout_s=300)
    if not (tmp / "runs" / "bench" / "report.md").is_file():
        raise RuntimeError("the compose run left no report.md")
    return up, run, down


def main() -> None:
    env = _env()
    if env is None:
        return
    print(f"scenario {SCENARIO.relative_to(ROOT)}, seed from the file; {os.cpu_count()} cores")
    podman_sh = [str(SCRIPT)]
    _rmi(SCRATCH_BASE, env)
    base_cold = _timed([*podman_sh, "base"], {**env, "FORMATION_BASE": SCRATCH_BASE})
    base_cached = _timed([*podman_sh, "base"], {**env, "FORMATION_BASE": SCRATCH_BASE})
    _rmi(SCRATCH_BASE, env)
    _timed([*podman_sh, "base"], env)  # the real base, cached from make compose-test
    cold = {**env, "FORMATION_IMAGE": SCRATCH_IMAGE, "FORMATION_BUILD_FLAGS": "--no-cache"}
    build_cold = _timed([*podman_sh, "build"], cold)
    _rmi(SCRATCH_IMAGE, env)
    build_cached = _timed([*podman_sh, "build"], env)
    size = _size_mb(env["FORMATION_IMAGE"], env)
    with tempfile.TemporaryDirectory(prefix="bench-containers-") as d:
        tmp = Path(d)
        _timed([sys.executable, "-m", "testbed.cli", "keys", str(tmp / "keys"), str(SCENARIO)], env)
        native = _timed([sys.executable, "-m", "testbed.cli", "run", str(SCENARIO),
                         "--runs-dir", str(tmp / "native")], env, cwd=tmp)  # fmt: skip
        up, run, down = _compose_run(env, tmp)
    total = up + run + down
    rows = [
        ("base image, cold (debootstrap or pull)", f"{base_cold:.1f} s"),
        ("base image, cached", f"{base_cached:.1f} s"),
        ("image build, cold (--no-cache)", f"{build_cold:.1f} s"),
        ("image build, cached", f"{build_cached:.1f} s"),
        ("image size", f"{size:.0f} MB"),
        ("native formation run [baseline]", f"{native:.1f} s"),
        ("podman-compose up", f"{up:.1f} s"),
        ("  → netem's exit", f"{run:.1f} s"),
        ("  → down (recorder finishes, report)", f"{down:.1f} s"),
        ("up → exit → down", f"{total:.1f} s  ({total / native:.2f} × native)"),
    ]
    width = max(len(r[0]) for r in rows)
    for name, value in rows:
        print(f"{name:<{width}}  {value}")


if __name__ == "__main__":
    main()
