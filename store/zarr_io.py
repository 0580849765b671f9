"""Running zarr's coroutines together (on object storage: one round of requests instead of one per
array)."""

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
