"""The files a Zenoh session's config names, checked readable before Zenoh reads them.

Zenoh reads them when the config loads or the session opens, and fails with its own error,
naming neither the user nor the fix: the compose deployment run as root without
``FORMATION_UID`` runs each service as uid 1000 against 0600 secrets owned by root (issue 26).
"""

from __future__ import annotations

import json
import os
import pwd
import stat
from typing import TYPE_CHECKING

from formation.errors import UnreadableFile

if TYPE_CHECKING:
    import zenoh

FILE_KEYS = (  # config keys whose value is a path Zenoh opens (zenoh 1.x)
    "transport/auth/usrpwd/dictionary_file",
    "transport/auth/pubkey/public_key_file",
    "transport/auth/pubkey/private_key_file",
    "transport/auth/pubkey/known_keys_file",
    "transport/link/tls/root_ca_certificate",
    "transport/link/tls/listen_private_key",
    "transport/link/tls/listen_certificate",
    "transport/link/tls/connect_private_key",
    "transport/link/tls/connect_certificate",
)


def check_readable(path: str, named_by: str) -> None:
    """Raise :class:`UnreadableFile` unless this process can open ``path`` for reading.

    Opening is the test (``os.access`` answers for the real uid and ignores some ACLs).
    """
    try:
        with open(path, "rb"):
            return
    except PermissionError:
        problem = "permission denied"
    except FileNotFoundError:
        problem = "no such file"
    except IsADirectoryError:
        problem = "is a directory"
    except OSError as exc:
        problem = (exc.strerror or str(exc)).lower()
    uid = os.geteuid()
    raise UnreadableFile(path, named_by, problem, uid, _user(uid), _owner(path))


def named_files(conf: zenoh.Config) -> list[tuple[str, str]]:
    """``(key, path)`` of every file ``conf`` names under :data:`FILE_KEYS`."""
    values = {key: json.loads(conf.get_json(key)) for key in FILE_KEYS}
    return [(key, str(path)) for key, path in values.items() if path is not None]


def check_config(conf: zenoh.Config) -> None:
    """Every file ``conf`` names is readable (else :class:`UnreadableFile`)."""
    for key, path in named_files(conf):
        check_readable(path, key)


def _user(uid: int) -> str:
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return "no name in /etc/passwd"  # a container's uid from FORMATION_UID, say


def _owner(path: str) -> tuple[int, str, int] | None:
    try:
        st = os.stat(path)
    except OSError:
        return None  # missing, or a folder on its path is closed to us
    return st.st_uid, _user(st.st_uid), stat.S_IMODE(st.st_mode)
