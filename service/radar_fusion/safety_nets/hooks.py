"""Site plug-ins of the safety nets, discovered through Python entry points.

:func:`load_hooks` discovers entry points in two groups: ``radar_fusion.alert_consumers``
(callables receiving each alert dict) and ``radar_fusion.alert_functions`` (objects, or
classes instantiated with ``(config, plane)``, with ``update(t_s, tracks) -> list[dict]``,
``tracks`` being the period's :class:`~radar_fusion.engine.columns.TrackColumns`; their
alerts are validated against ``wire.Alert`` and published as they are). A hook that
raises is caught by :class:`~radar_fusion.safety_nets.SafetyNets`, logged at a bounded
rate and counted in ``hook_errors``; it never stops the daemon.
"""

from __future__ import annotations

import inspect
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import metadata
from typing import Any

from ..geo.coordinates import SystemPlane
from .config import SafetyNetsConfig

log = logging.getLogger(__name__)

CONSUMER_GROUP = "radar_fusion.alert_consumers"
FUNCTION_GROUP = "radar_fusion.alert_functions"


@dataclass
class Hooks:
    """Site plug-ins: alert consumers and extra alert functions, by entry-point name."""

    consumers: list[tuple[str, Callable[[dict], Any]]] = field(default_factory=list)
    functions: list[tuple[str, Any]] = field(default_factory=list)
    load_errors: dict[str, str] = field(default_factory=dict)


def _entry_points(group: str) -> list[Any]:
    eps = metadata.entry_points()
    if hasattr(eps, "select"):
        return list(eps.select(group=group))
    return list(eps.get(group, []))  # Python < 3.10 API


def load_hooks(config: SafetyNetsConfig | None = None, plane: SystemPlane | None = None) -> Hooks:
    """Discover hooks through ``importlib.metadata`` entry points.

    ``radar_fusion.alert_consumers``: each entry point loads a callable ``f(alert_dict)``
    (a class is instantiated with no arguments first). ``radar_fusion.alert_functions``:
    each loads an object with ``update(t_s, tracks) -> list[dict]``, or a class, which is
    instantiated as ``cls(config, plane)`` when it takes two arguments, else ``cls()``.
    An entry point that fails to load is logged and listed in ``load_errors``.
    """
    hooks = Hooks()
    for group in (CONSUMER_GROUP, FUNCTION_GROUP):
        for ep in _entry_points(group):
            name = f"{group}:{ep.name}"
            try:
                obj = ep.load()
                if inspect.isclass(obj):
                    hook_cls: type[Any] = obj  # isclass() narrows to type[object], which takes no arguments
                    if group == FUNCTION_GROUP and _positional_arity(hook_cls) >= 2:
                        obj = hook_cls(config, plane)
                    else:
                        obj = hook_cls()
                if group == CONSUMER_GROUP:
                    if not callable(obj):
                        raise TypeError("alert consumer is not callable")
                    hooks.consumers.append((ep.name, obj))
                else:
                    if not callable(getattr(obj, "update", None)):
                        raise TypeError("alert function has no update(t_s, tracks)")
                    hooks.functions.append((ep.name, obj))
            except Exception as exc:  # a broken plug-in must not stop the daemon
                hooks.load_errors[name] = f"{type(exc).__name__}: {exc}"
                log.error("safety-net hook %s failed to load: %s", name, exc)
    return hooks


def _positional_arity(cls: type) -> int:
    try:
        params = list(inspect.signature(cls).parameters.values())
    except (TypeError, ValueError):
        return 0
    if any(p.kind == p.VAR_POSITIONAL for p in params):
        return 2
    return sum(p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD) for p in params)
