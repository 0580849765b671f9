"""Episodes' instructions: what each episode was told to do, in words (the episode table's column).

``demo collect --instruction TEXT`` writes it for every episode; a Gymnasium environment's own
(``env.instruction``, or its adapter's: Meta-World's task as a sentence) is written without it. An
instruction-conditioned policy (:mod:`demo.policies.instruction`) trains on it; a store without the
column holds no instructions. Whitespace runs are one space.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from demo.errors import DemoError

INSTRUCTION_COLUMN = "instruction"  # string, "" or null = none
MAX_CHARACTERS = 500  # an instruction longer than this is refused (a paragraph, not an instruction)


def normalized(text: Any) -> str:
    """``text`` with its whitespace runs made one space ("" for None)."""
    return "" if text is None else " ".join(str(text).split())


def check_instruction(text: str, where: str = "--instruction") -> str:
    """``text`` normalised, or a DemoError for an empty or over-long instruction."""
    stripped = normalized(text)
    if not stripped:
        raise DemoError(where, "is empty: give the task in words, e.g. 'open the drawer'")
    if len(stripped) > MAX_CHARACTERS:
        raise DemoError(where, f"is {len(stripped)} characters long; an instruction is at most {MAX_CHARACTERS}")
    return stripped


def episode_instructions(stores: Sequence[Any]) -> list[str]:
    """Each episode's instruction, store after store (open :class:`~demo.store.EpisodeStore` s; "" where
    a store has none)."""
    out: list[str] = []
    for store in stores:
        if INSTRUCTION_COLUMN in store.table.column_names:
            out += [normalized(t) for t in store.column(INSTRUCTION_COLUMN).tolist()]
        else:
            out += [""] * store.num_episodes
    return out
