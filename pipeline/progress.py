"""A progress bar on stderr for commands that walk a whole log; silent when stderr is not a terminal or with --quiet."""

from __future__ import annotations

import sys
import threading
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from typing import TypeVar

from tqdm import tqdm

T = TypeVar("T")


def enabled(quiet: bool = False) -> bool:
    """Whether a bar should be drawn: stderr is a terminal and the user did not ask for quiet."""
    return not quiet and sys.stderr.isatty()


def bar(total: int | None = None, desc: str = "", unit: str = "scan", *, show: bool | None = None) -> tqdm:
    """A tqdm bar on stderr; `show=None` decides by `enabled()`. Use as a context manager, `.update(n)`."""
    return tqdm(
        total=total,
        desc=desc,
        unit=unit,
        file=sys.stderr,
        disable=not (enabled() if show is None else show),
        dynamic_ncols=True,
        leave=False,
    )


def track(
    items: Iterable[T], total: int | None = None, desc: str = "", unit: str = "scan", *, show: bool | None = None
) -> Iterator[T]:
    """Iterate `items` with a bar that closes when the iteration ends or is abandoned."""
    with bar(total, desc, unit, show=show) as b:
        for item in items:
            yield item
            b.update(1)


def note(text: str) -> None:
    """A note on stderr (stdout may carry JSON): something the tool did on its own, such as dropping points."""
    print(f"aftershock: note: {text}", file=sys.stderr)


@contextmanager
def working(desc: str, *, show: bool | None = None, tick_s: float = 0.5) -> Iterator[None]:
    """A line on stderr with the time a step without steps of its own has taken so far (`refining: 00:07`),
    redrawn every `tick_s` and cleared at the end; `show=None` decides by `enabled()`."""
    if not (enabled() if show is None else show):
        yield
        return
    line = tqdm(desc=desc, bar_format="{desc}: {elapsed}", file=sys.stderr, leave=False, dynamic_ncols=True)
    done = threading.Event()

    def tick() -> None:
        while not done.wait(tick_s):
            line.refresh()

    ticker = threading.Thread(target=tick, name="aftershock-progress", daemon=True)
    ticker.start()
    try:
        yield
    finally:
        done.set()
        ticker.join()
        line.close()
