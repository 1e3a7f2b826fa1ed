"""What a command's job returns: its summary (lines for the terminal) and its JSON record (``hd --json``)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Done:
    """A finished job: ``lines`` for standard output (dropped by ``hd -q`` and ``hd --json``) and
    ``record``, the one JSON object ``hd --json`` prints instead."""

    lines: list[str] = field(default_factory=list)
    record: dict[str, object] = field(default_factory=dict)


def counted(n: int, noun: str) -> str:
    """``n`` and ``noun`` in the singular or the plural (an ``s`` added): ``1 shard``, ``3 shards``."""
    return f"{n} {noun}{'' if n == 1 else 's'}"
