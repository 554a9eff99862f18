"""A service started as a user who cannot read a file, on root and non-root alike (issue 26).

Root reads any file whatever its mode, so chmod alone proves nothing there. Run as root, the
service starts as root (the interpreter may live under /root), imports the product, then
drops to an unused uid before it runs: the compose deployment's uid 1000 against root's 0600
secrets. Run as anyone else, the file is made mode 000 and the service runs as that user.
``python -m testkit.other_user UID MODULE ARGS...`` is the dropping step.
"""

from __future__ import annotations

import grp
import importlib.util
import os
import pwd
import sys
from pathlib import Path

AS_ROOT = os.geteuid() == 0


def unused_id(start: int = 50_000) -> int:
    """The first id from ``start`` that is neither a user's nor a group's."""
    for i in range(start, start + 10_000):
        try:
            pwd.getpwuid(i)
        except KeyError:
            try:
                grp.getgrgid(i)
            except KeyError:
                return i
    raise LookupError(f"no unused id in {start}..{start + 10_000}")


OTHER = unused_id() if AS_ROOT else os.geteuid()  # the uid the service runs as


def command(module: str, *args: str) -> list[str]:
    """``python -P -m MODULE ARGS`` as :data:`OTHER`."""
    if AS_ROOT:
        return [sys.executable, "-P", "-m", "testkit.other_user", str(OTHER), module, *args]
    return [sys.executable, "-P", "-m", module, *args]


def shut(path: Path) -> None:
    """Make ``path`` unreadable by :data:`OTHER`: root's 0600 as root (as ``formation keys``
    writes it), else mode 000."""
    os.chmod(path, 0o600 if AS_ROOT else 0o000)


def hand_over(path: Path) -> None:
    """Let :data:`OTHER` write ``path`` (a folder: enter it), so what it leaves is its choice."""
    if AS_ROOT:
        os.chown(path, OTHER, OTHER)
    os.chmod(path, 0o755 if path.is_dir() else 0o644)


def main(argv: list[str]) -> None:
    uid, module, *args = argv
    # What the services import, and the code `python -m MODULE` runs, read while root still
    # can: the checkout may sit in a folder only root may enter (mktemp -d is 0700).
    import agent.node  # noqa: F401
    import leader.node  # noqa: F401
    import netem.node  # noqa: F401
    import recorder.node  # noqa: F401
    import testbed.runtime.router  # noqa: F401
    from formation.plugin_registry import GROUPS, registered

    for kind in GROUPS:  # the plug-ins' entry points: the venv's metadata, read as root
        registered(kind)

    spec = importlib.util.find_spec(module)
    if spec is not None and spec.submodule_search_locations is not None:  # a package
        spec = importlib.util.find_spec(f"{module}.__main__")
    if spec is None or spec.loader is None:
        raise SystemExit(f"other_user: no module {module}")
    code = spec.loader.get_code(spec.name)  # type: ignore[attr-defined]
    os.setgroups([])
    os.setgid(int(uid))
    os.setuid(int(uid))
    sys.argv = [spec.origin or module, *args]
    run_as = {"__name__": "__main__", "__spec__": spec, "__file__": spec.origin,
              "__package__": spec.parent, "__builtins__": __builtins__}  # fmt: skip
    exec(code, run_as)


if __name__ == "__main__":
    main(sys.argv[1:])
