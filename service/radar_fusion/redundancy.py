"""A hot-standby pair (or more) of fusion daemons on one Zenoh bus (issue 13).

With ``[redundancy] enabled = true``, every ``radar-fusion serve`` of one configuration
joins the election under ``<prefix>/fusion/redundancy/``:

    member/<instance>            a liveliness token while the process is on the bus
    active/<instance>/<epoch>    a liveliness token while it is the active

Zenoh withdraws a token when its session ends: at once when the process dies (SIGKILL
included: the router sees the link close), or after ``[redundancy] lease_s`` when the
host goes down or the link is cut. Every member watches both key sets.

The rules, which :class:`Election` implements without any I/O:

* **One active.** A standby takes over when it sees no active (it has asked the bus
  for the tokens alive at its start, and listened ``settle_s`` more), and is the smallest
  instance name among the standbys it sees (so of three, one moves). It takes the epoch
  one above the highest it has seen (on tokens, TrackBatches and states) and at least the
  wall clock's UTC seconds, so epochs only grow, also across a restart of the whole pair.
* **Two actives** (a partition healed, or two standbys moved at once): the one of the
  lower epoch stands down at once; at equal epochs the larger name does. A TrackBatch or
  state of a higher epoch than its own makes an active stand down too, before the token
  arrives. Every message an active publishes carries its epoch, so a consumer can drop
  a stale active's last messages (the highest epoch wins).

What the daemon does with its role (bus.py): the active closes periods and publishes
tracks, alerts and, after each period, its track state on ``<prefix>/fusion/state``
(engine/state.py, ``wire.FusionState``); a standby ingests the same plots but closes no
period: it applies each state it receives, which replaces its tracks and drops the plots
of the periods the active has closed, so it holds the same tracks with the same ids. When
it takes over it closes the periods after the newest state, and does not publish a period
the lost active has already published (it saw its TrackBatch): every period once.
"""

from __future__ import annotations

import logging
import math
import os
import socket
from dataclasses import dataclass, field
from typing import Any, Literal

log = logging.getLogger("radar_fusion.redundancy")

Role = Literal["active", "standby"]


def default_instance() -> str:
    """``<hostname>:<pid>``, in the characters a Zenoh key chunk may hold."""
    host = "".join(c if c.isalnum() or c in "_.-" else "_" for c in socket.gethostname()) or "host"
    return f"{host[:48]}:{os.getpid()}"


def election_keys(prefix: str) -> tuple[str, str]:
    """(member key set, active key set) under ``<prefix>/fusion/redundancy``."""
    return f"{prefix}/fusion/redundancy/member", f"{prefix}/fusion/redundancy/active"


@dataclass
class Election:
    """Who is active, from what the bus shows (the module docstring's rules). Time is
    passed in (monotonic seconds), so a test drives it exactly."""

    instance: str
    started_s: float
    settle_s: float = 1.0
    handover_s: float = 0.0  # after the last active's token went, wait this long (RedundancyConfig.handover_s)
    role: Role = "standby"
    epoch: int = 0  # ours while active
    highest_epoch: int = 0  # the highest seen anywhere, ours included
    actives: dict[str, int] = field(default_factory=dict)  # other instances' active tokens → epoch
    members: set[str] = field(default_factory=set)  # other instances on the bus
    takeovers: int = 0
    stand_downs: int = 0
    active_gone_s: float = -math.inf  # when the last active token seen was withdrawn

    # ------------------------------------------------------------- what is seen
    def member_seen(self, instance: str, alive: bool) -> None:
        if instance != self.instance:
            (self.members.add if alive else self.members.discard)(instance)

    def active_seen(self, instance: str, epoch: int, alive: bool, now_s: float = -math.inf) -> None:
        """An active token appeared (``alive``) or was withdrawn (seen at ``now_s``)."""
        if instance == self.instance:
            return
        if alive:
            self.actives[instance] = max(epoch, self.actives.get(instance, 0))
            self.highest_epoch = max(self.highest_epoch, epoch)
        elif self.actives.get(instance) == epoch:
            del self.actives[instance]
            self.active_gone_s = max(self.active_gone_s, now_s)

    def epoch_seen(self, instance: str | None, epoch: int) -> None:
        """A TrackBatch or state of ``epoch`` from ``instance`` (an active's stamp)."""
        self.highest_epoch = max(self.highest_epoch, epoch)
        newer = instance is not None and (epoch, _rank(instance)) > (self.epoch, _rank(self.instance))
        if newer and instance != self.instance and self.role == "active":
            assert instance is not None
            self.actives[instance] = max(epoch, self.actives.get(instance, 0))

    # ------------------------------------------------------------------ decide
    def decide(self, now_s: float) -> Literal["take_over", "stand_down"] | None:
        """What to do now; the caller then calls :meth:`took_over` or :meth:`stood_down`."""
        if self.role == "active":
            mine = (self.epoch, _rank(self.instance))
            if any((e, _rank(i)) > mine for i, e in self.actives.items()):
                return "stand_down"
            return None
        if self.actives or now_s - self.started_s < self.settle_s:
            return None
        if now_s - self.active_gone_s < self.handover_s:
            return None  # the gone active's last TrackBatches may still be on their way
        standbys = self.members - set(self.actives)
        if any(_rank(i) > _rank(self.instance) for i in standbys):
            return None  # another standby comes first; if it does not move, it is not on the bus
        return "take_over"

    def took_over(self, wall_s: float = 0.0) -> int:
        """Become the active: the epoch is one above the highest seen, and at least the
        wall clock's whole seconds (``wall_s``), so that epochs also grow across a restart
        of the whole pair (a display that stayed up would otherwise drop the new active's
        messages as stale)."""
        self.role = "active"
        self.epoch = self.highest_epoch = max(self.highest_epoch + 1, int(wall_s))
        self.takeovers += 1
        return self.epoch

    def stood_down(self) -> None:
        self.role = "standby"
        self.stand_downs += 1


def _rank(instance: str) -> tuple[int, ...]:
    """Ordering of instance names: the smaller name ranks higher (negated code points)."""
    return tuple(-ord(c) for c in instance) + (0,)


class ElectionOnBus:
    """The liveliness tokens and subscribers of one daemon; events go to ``events`` (a
    callable taking ``(kind, instance, epoch, alive)``, called on Zenoh's threads)."""

    def __init__(self, session: Any, prefix: str, instance: str, events: Any):
        self.session = session
        self.member_key, self.active_key = election_keys(prefix)
        self.instance = instance
        self._events = events
        self._member_token = session.liveliness().declare_token(f"{self.member_key}/{instance}")
        self._active_token: Any = None
        self._subs = [
            session.liveliness().declare_subscriber(f"{self.member_key}/*", self._on_member, history=True),
            session.liveliness().declare_subscriber(f"{self.active_key}/*/*", self._on_active, history=True),
        ]

    def _on_member(self, sample: Any) -> None:
        instance = str(sample.key_expr).rsplit("/", 1)[-1]
        self._events("member", instance, 0, _alive(sample))

    def _on_active(self, sample: Any) -> None:
        *_, instance, epoch = str(sample.key_expr).split("/")
        try:
            self._events("active", instance, int(epoch), _alive(sample))
        except ValueError:
            log.warning("ignoring an active token with a bad epoch: %s", sample.key_expr)

    def scan(self, timeout_s: float) -> int:
        """Ask the bus for the tokens alive now (a liveliness query, answered when every
        router has replied) and hand them over as events before the caller decides: under
        load the subscribers' history can come later than any fixed wait (a standby that
        started on a busy host once took over for a moment beside a live active).
        Returns the tokens seen."""
        seen = 0
        for key, handler in ((f"{self.member_key}/*", self._on_member), (f"{self.active_key}/*/*", self._on_active)):
            for reply in self.session.liveliness().get(key, timeout=timeout_s):
                if reply.ok is not None:
                    handler(reply.ok)
                    seen += 1
        return seen

    def declare_active(self, epoch: int) -> None:
        self.withdraw_active()
        self._active_token = self.session.liveliness().declare_token(f"{self.active_key}/{self.instance}/{epoch}")

    def withdraw_active(self) -> None:
        if self._active_token is not None:
            self._active_token.undeclare()
            self._active_token = None

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()
        self._subs = []
        self.withdraw_active()
        self._member_token.undeclare()


def _alive(sample: Any) -> bool:
    import zenoh

    return bool(sample.kind == zenoh.SampleKind.PUT)
