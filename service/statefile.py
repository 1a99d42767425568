"""The session registry on disk (``--state-file``): what a restarted instance resumes.

Across instances the registry lives on Zenoh (``service/cluster.py``); a single instance that
restarts has nobody to ask. So the registry, each session with its last box, is also written
to a file: at most every ``SAVE_PERIOD_S`` while something changed (a start, a stop, a newer
box), and once more when the instance stops. An instance started with the same file merges
it before it joins, and resumes those sessions of streams it owns from their last box
(status ``resumed``), as it would take over a dead instance's: after a SIGKILL the box is at
most ``SAVE_PERIOD_S`` plus ``last_box_period_ms`` old. Where other instances are live, their
registry is the truth and the file is not read (a session stopped meanwhile stays stopped);
it is written all the same.

One line per session, the ``session_spec`` message as JSON (``arcf.schemas.to_json``), read
back through the same validation as the wire's (``from_json``): a damaged line is skipped with
a warning, never trusted. The file is replaced atomically (written beside it, then renamed), so
a crash mid-write leaves the previous one.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable
from pathlib import Path

from arcf.schemas import SchemaError, SessionSpec, from_json, to_json

log = logging.getLogger(__name__)

#: how often a changed registry is written at most
SAVE_PERIOD_S = 0.5
#: the most sessions read back (the registry of a service that runs far fewer)
MAX_ENTRIES = 65536


class StateFile:
    """Reads and writes the registry at ``path`` (its folder must exist)."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def load(self) -> list[SessionSpec]:
        """The sessions of the last write; none when there is no file yet."""
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return []
        except (OSError, UnicodeDecodeError) as exc:
            log.warning("state file %s unreadable, no session resumed from it: %s",
                        self.path, exc)
            return []
        specs = []
        for number, line in enumerate(text.splitlines()[:MAX_ENTRIES], 1):
            if not line.strip():
                continue
            try:
                specs.append(from_json(line, expected=SessionSpec))
            except SchemaError as exc:
                log.warning("state file %s line %d skipped: %s", self.path, number, exc)
        return [s for s in specs if isinstance(s, SessionSpec)]

    def save(self, specs: Iterable[SessionSpec]) -> None:
        """Replace the file with ``specs``, atomically."""
        part = self.path.with_name(f".{self.path.name}.{os.getpid()}.part")
        with open(part, "wb") as out:
            for spec in specs:
                out.write(to_json(spec) + b"\n")
            out.flush()
            os.fsync(out.fileno())
        os.replace(part, self.path)
