"""Containers for real: what podman costs against a native run, measured in the same run.

Run ``python -m bench bench_containers`` from the checkout (``make compose-test`` installs
podman first; without podman, or when a step fails, this prints why and skips the rest instead
of aborting ``make bench``). Measured:

1. The base image (the Dockerfile's ``FROM``) made locally with debootstrap, as
   ``deploy/podman.sh base`` does when no registry serves it: cold (under a scratch tag that no
   registry serves, so the real one stays cached and the pull fails at once) and cached. Making
   it needs root; without root, or when it fails, the rows say skipped and the rest runs.
2. The image build, cold (``--no-cache``: every dependency downloaded and installed) and cached
   (the same tree again: every layer from the cache), both from one copy of the checkout, and
   the image's size.
3. ``podman-compose up`` → netem's exit → ``down`` of the unchanged ``compose.yaml`` with the
   loopback override, against the baseline ``formation run`` of the same scenario and seed
   (``scenarios/paper.toml``, its seed printed), each timed end to end as a user runs it.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from formation.scenario import Scenario

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "deploy" / "podman.sh"
SCENARIO = ROOT / "scenarios" / "paper.toml"
SCRATCH_BASE = "localhost/formation-bench-base:cold"
SCRATCH_IMAGE = "localhost/formation-bench:cold"
# Not copied for the builds (.dockerignore leaves them out of the image anyway).
NOT_BUILT = (".git", ".venv", "runs", "keys", "experiments", "build", "__pycache__", "*.egg-info",
             ".pytest_cache", ".mypy_cache", ".ruff_cache", ".hypothesis")  # fmt: skip


def _env() -> dict[str, str] | None:
    """The variables of ``deploy/podman.sh env``; None (and why) when podman is not there."""
    if shutil.which("podman") is None:
        print("podman is not installed: skipped (make compose-test installs it)")
        return None
    out = subprocess.run([str(SCRIPT), "env"], capture_output=True, text=True, check=False)
    env = dict(line.split("=", 1) for line in out.stdout.splitlines() if "=" in line)
    if out.returncode != 0 or not {"PODMAN_COMPOSE", "CONTAINERS_CONF"} <= env.keys():
        print(f"deploy/podman.sh env failed: skipped ({out.stderr.strip()[-300:]})")
        return None
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
    """Seconds of ``up``, of netem's run until its exit, and of ``down``; netem must exit 0."""
    compose = [env["PODMAN_COMPOSE"], "-f", "compose.yaml", "-f", "deploy/compose.loopback.yaml"]
    run_env = {**env, "FORMATION_KEYS": str(tmp / "keys"), "FORMATION_RUNS": str(tmp / "runs"),
               "RUN_ID": "bench", "FORMATION_UID": str(os.getuid()),
               "FORMATION_GID": str(os.getgid())}  # fmt: skip
    (tmp / "runs").mkdir()
    up = _timed([*compose, "up", "-d"], run_env)
    try:
        t0 = time.perf_counter()
        wait = subprocess.run(["podman", "wait", "formation_netem_1"], env=run_env,
                              capture_output=True, text=True, timeout=600)  # fmt: skip
        run = time.perf_counter() - t0
    finally:
        down = _timed([*compose, "down"], run_env, timeout_s=300)
    if wait.returncode != 0 or wait.stdout.strip() != "0":
        raise RuntimeError(
            f"netem exited with {wait.stdout.strip() or '?'} (podman wait: {wait.returncode}) "
            f"{wait.stderr[-500:]}"
        )
    if not (tmp / "runs" / "bench" / "report.md").is_file():
        raise RuntimeError("the compose run left no report.md")
    return up, run, down


def _skipped(what: str, why: str) -> None:
    print(f"{what}: skipped ({why})")


def _base_rows(env: dict[str, str]) -> list[tuple[str, str]]:
    """The base image made with debootstrap, cold and cached, under the scratch tag."""
    label = "base image, cold (made locally: debootstrap + apt)"
    if os.getuid() != 0:
        _skipped(label, "making the base image needs root: debootstrap, chroot")
        return []
    scratch = {**env, "FORMATION_BASE": SCRATCH_BASE}
    _rmi(SCRATCH_BASE, env)
    try:
        cold = _timed([str(SCRIPT), "base"], scratch)
        cached = _timed([str(SCRIPT), "base"], scratch)
    except RuntimeError as exc:
        _skipped(label, f"deploy/podman.sh base failed: {str(exc).strip().splitlines()[-1]}")
        return []
    finally:
        _rmi(SCRATCH_BASE, env)
    return [(label, f"{cold:.1f} s"), ("base image, cached (already in podman's store)",
                                       f"{cached:.1f} s")]  # fmt: skip


def main() -> None:
    env = _env()
    if env is None:
        return
    seed = Scenario.from_file(SCENARIO).seed
    print(f"scenario {SCENARIO.relative_to(ROOT)}, seed {seed}; {os.cpu_count()} cores; "
          f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")  # fmt: skip
    rows = _base_rows(env)
    try:
        _timed([str(SCRIPT), "base"], env)  # the real base, cached from make compose-test
    except RuntimeError as exc:
        _skipped("the image and the compose run", f"no base image {exc}")
        return
    cold = {**env, "FORMATION_IMAGE": SCRATCH_IMAGE, "FORMATION_BUILD_FLAGS": "--no-cache"}
    with tempfile.TemporaryDirectory(prefix="bench-containers-") as d:
        tmp = Path(d)
        # Both builds from one copy of the tree: an edit in between (pyproject.toml above all)
        # would make the cached build a cold one.
        shutil.copytree(ROOT, tmp / "tree", ignore=shutil.ignore_patterns(*NOT_BUILT))
        script = str(tmp / "tree" / SCRIPT.relative_to(ROOT))
        try:
            build_cold = _timed([script, "build"], cold)
            build_cached = _timed([script, "build"], env)  # the same tree, every layer cached
        except RuntimeError as exc:
            _skipped("the image and the compose run", f"the build failed: {exc}")
            return
        finally:
            _rmi(SCRATCH_IMAGE, env)  # only the tag: the layers are the real image's now
        size = _size_mb(env["FORMATION_IMAGE"], env)
        _timed([sys.executable, "-m", "testbed.cli", "keys", str(tmp / "keys"), str(SCENARIO)], env)
        native = _timed([sys.executable, "-m", "testbed.cli", "run", str(SCENARIO),
                         "--runs-dir", str(tmp / "native")], env, cwd=tmp)  # fmt: skip
        up, run, down = _compose_run(env, tmp)
    total = up + run + down
    rows += [
        ("image build, cold (--no-cache)", f"{build_cold:.1f} s"),
        ("image build, cached", f"{build_cached:.1f} s"),
        ("image size", f"{size:.0f} MB"),
        ("native formation run [baseline]", f"{native:.1f} s"),
        ("podman-compose up", f"{up:.1f} s"),
        ("  → netem's exit (0)", f"{run:.1f} s"),
        ("  → down (recorder finishes, report)", f"{down:.1f} s"),
        ("up → exit → down", f"{total:.1f} s  ({total / native:.2f} × native)"),
    ]
    width = max(len(r[0]) for r in rows)
    for name, value in rows:
        print(f"{name:<{width}}  {value}")
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
