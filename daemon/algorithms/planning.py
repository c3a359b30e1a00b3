"""Plans off the control tick: one worker thread per behaviour, and one convention for all.

Nothing may block the tick (a 1 kHz loop has 1 ms; a joist crossing plan takes 0.2-2 s), so a
behaviour hands its planner call to a ``PlanWorker`` and goes on:

- it holds a safe posture (feet where they stand) until ``take()`` returns the outcome;
- an outcome whose inputs have gone stale (the body moved past the plan's tolerance while it
  was made) is re-checked against the current state, and re-requested if it no longer fits;
- a failed plan comes back as ``Outcome.error``; the behaviour logs its reason once and decides
  (go round, back off, hold), while an unexpected error is re-raised so the runtime isolates
  the plugin (HOLD).

In simulated time (``wait=True``: the twin, tests, benches) ``take()`` waits for the plan, so a
stepped run is deterministic and decides exactly as a synchronous planner would.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Generic, TypeVar

T = TypeVar("T")


@dataclass(frozen=True)
class Outcome(Generic[T]):
    """What a plan request came to: the plan, or the exception the planner raised."""

    plan: T | None = None
    error: Exception | None = None


class PlanWorker(Generic[T]):
    """One planner call at a time on a thread of its own; ``take`` never waits (unless
    ``wait``), so the tick that asks goes on at once."""

    def __init__(self, name: str, wait: bool = False) -> None:
        self.name = name
        self.wait = wait
        self._executor: ThreadPoolExecutor | None = None
        self._pending: Future[T] | None = None

    @property
    def pending(self) -> bool:
        """A plan has been requested and not yet taken."""
        return self._pending is not None

    @property
    def ready(self) -> bool:
        """The requested plan is done and waits to be taken."""
        return self._pending is not None and self._pending.done()

    def request(self, plan: Callable[..., T], *args: object) -> None:
        """Start ``plan(*args)`` on the worker; the caller passes inputs it will not change
        (copies), so the plan depends on nothing the tick goes on writing."""
        if self._executor is None:
            self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix=self.name)
        self._pending = self._executor.submit(plan, *args)

    def take(self) -> Outcome[T] | None:
        """The outcome once the requested plan is done, else None without waiting (``wait``
        mode: waits for it)."""
        pending = self._pending
        if pending is None or not (self.wait or pending.done()):
            return None
        self._pending = None
        try:
            return Outcome(plan=pending.result())
        except Exception as e:
            return Outcome(error=e)

    def close(self) -> None:
        """Stop the worker: a queued plan is dropped, one under way ends on its own."""
        self._pending = None
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None
