"""The CMRTs shipped with the project (``cmrt/assets/library.json``).

``--curve library`` looks a task and speed up here, so users can run the paper's
results without optimizing. Entries are written by ``tools/find_library_curve.py``.
"""

from __future__ import annotations

import json
from pathlib import Path

from cmrt.curve import Cmrt
from cmrt.errors import CmrtError
from cmrt.task import Task

LIBRARY_PATH = Path(__file__).parent / "assets" / "library.json"
SPEED_TOLERANCE = 1e-9


def load_entries(path: Path = LIBRARY_PATH) -> list[dict]:
    if not path.exists():
        return []
    return json.loads(path.read_text())["entries"]


def library_curve(task: Task, path: Path = LIBRARY_PATH) -> Cmrt:
    """The shipped CMRT for this task at exactly this speed."""
    for entry in load_entries(path):
        if entry["task"] != task.name:
            continue
        if task.speed is None or abs(entry["speed"] - task.speed) <= SPEED_TOLERANCE:
            return Cmrt.from_dict(entry["cmrt"])
    speeds = [e["speed"] for e in load_entries(path) if e["task"] == task.name]
    have = f" (library has speeds {', '.join(f'{s:g}' for s in speeds)})" if speeds else ""
    raise CmrtError(f"no library CMRT for task '{task.name}' at speed {task.speed}{have}")


def save_entry(entry: dict, path: Path = LIBRARY_PATH) -> None:
    """Insert or replace the entry for (task, speed), keeping the file sorted."""
    entries = [e for e in load_entries(path) if not (e["task"] == entry["task"] and e["speed"] == entry["speed"])]
    entries.append(entry)
    entries.sort(key=lambda e: (e["task"], e["speed"]))
    path.write_text(json.dumps({"entries": entries}, indent=2) + "\n")
