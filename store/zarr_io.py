"""Running zarr's coroutines together (on object storage: one round of requests instead of one per
array), and an exception's first line for the store's error messages."""

from __future__ import annotations

import asyncio
from typing import Any

from zarr.core.sync import sync


def run_concurrently(coroutines: list[Any]) -> None:
    """Run zarr coroutines together; the first failure is raised."""
    for result in sync(gather(*coroutines)) if coroutines else ():
        if isinstance(result, BaseException):
            raise result


async def gather(*coroutines: Any) -> list[Any]:
    """Every coroutine's result or exception (none is left running when another fails)."""
    return await asyncio.gather(*coroutines, return_exceptions=True)


def first_line(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text.splitlines()[0][:200]
