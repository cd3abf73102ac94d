"""``serve`` runs the safety nets as its child process, and keeps it running.

:class:`SafetyNetsChild` starts ``radar-fusion safety-nets --settings-from-stdin`` (the
daemon's effective settings as one JSON line on the child's stdin, area and MSA file
paths made absolute), in its own process group so that a Ctrl-C at the terminal reaches
serve alone, which then stops the child in order.

Lifetime:
* the child's stdin is a pipe whose write end only serve holds. Closing it is the clean
  stop (the child judges the batches in flight, publishes its final health and exits);
  serve dying in any way, SIGKILL included, closes it too, so the child never outlives
  serve (no orphan). SIGTERM after ``STOP_TIMEOUT_S``, SIGKILL after as long again;
* a child that exits while serve runs is started again after ``RESTART_DELAY_S``
  (doubling, up to ``MAX_RESTART_DELAY_S``, while it keeps dying within
  ``STABLE_AFTER_S`` of its start), counted in ``restarts`` and logged with its exit code.
  Alerts are not judged while it is down (a few seconds: the imports); the new child
  starts with no open alert and confirms conflicts again over its periods.
"""

from __future__ import annotations

import contextlib
import json
import logging
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..config import Settings

log = logging.getLogger("radar_fusion.safety_nets.supervisor")

RESTART_DELAY_S = 1.0
MAX_RESTART_DELAY_S = 30.0
STABLE_AFTER_S = 60.0
STOP_TIMEOUT_S = 10.0


def child_settings_json(settings: Settings, base_dir: Path | None) -> str:
    """The settings as the child reads them: one JSON line, file paths absolute."""
    data = settings.model_dump(mode="json")
    nets = data["safety_nets"]
    for key in ("areas_file", "msa_file", "zenoh_config_file"):
        if nets.get(key):
            p = Path(nets[key])
            nets[key] = str(p if p.is_absolute() or base_dir is None else (Path(base_dir) / p).resolve())
    return json.dumps(data)


class SafetyNetsChild:
    """The supervised ``radar-fusion safety-nets`` child (see the module docstring)."""

    def __init__(
        self,
        settings: Settings,
        base_dir: Path | None = None,
        log_level: str | None = None,
        log_format: str = "text",
        command: list[str] | None = None,
    ):
        self.settings_line = child_settings_json(settings, base_dir).encode() + b"\n"
        level = log_level or logging.getLevelName(logging.getLogger().getEffectiveLevel())
        self.command = command or [
            sys.executable,
            "-m",
            "radar_fusion.cli",
            "safety-nets",
            "--settings-from-stdin",
            "--log-level",
            str(level),
            "--log-format",
            log_format,
        ]
        self.proc: subprocess.Popen | None = None
        self.restarts = 0
        self.last_exit_code: int | None = None
        self.started_s = 0.0
        self._lock = threading.Lock()
        self._stopping = threading.Event()
        self._monitor: threading.Thread | None = None

    @property
    def pid(self) -> int | None:
        return self.proc.pid if self.proc is not None else None

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def start(self) -> SafetyNetsChild:
        self._spawn()
        self._monitor = threading.Thread(target=self._watch, name="safety-nets-supervisor", daemon=True)
        self._monitor.start()
        return self

    def _spawn(self) -> None:
        with self._lock:
            proc = subprocess.Popen(self.command, stdin=subprocess.PIPE, start_new_session=True)
            assert proc.stdin is not None
            try:
                proc.stdin.write(self.settings_line)
                proc.stdin.flush()  # stdin stays open: its end is the stop signal
            except BrokenPipeError:
                pass  # it died at once; _watch sees it
            self.proc, self.started_s = proc, time.monotonic()
        log.info("safety nets started as child process %d", proc.pid)

    def _watch(self) -> None:
        delay_s = RESTART_DELAY_S
        while not self._stopping.wait(0.2):
            proc = self.proc
            if proc is None or proc.poll() is None:
                continue
            self.last_exit_code = proc.returncode
            if proc.stdin is not None:
                proc.stdin.close()
            lived_s = time.monotonic() - self.started_s
            log.error(
                "safety-nets child %d exited with code %s after %.0f s; restarting in %.0f s",
                proc.pid,
                proc.returncode,
                lived_s,
                delay_s if lived_s < STABLE_AFTER_S else RESTART_DELAY_S,
            )
            if lived_s >= STABLE_AFTER_S:
                delay_s = RESTART_DELAY_S
            if self._stopping.wait(delay_s):
                return
            delay_s = min(2 * delay_s, MAX_RESTART_DELAY_S)
            self.restarts += 1
            try:
                self._spawn()
            except OSError:
                log.exception("starting the safety-nets child failed")

    def no_more_restarts(self) -> None:
        """serve is stopping: a child that exits now (e.g. SIGTERM from a service manager that
        signals the whole group) is not started again; a running one goes on until :meth:`stop`."""
        self._stopping.set()

    def stop(self, timeout_s: float = STOP_TIMEOUT_S) -> int | None:
        """Close the child's stdin (its clean stop), wait; SIGTERM, then SIGKILL. Returns its exit code."""
        self._stopping.set()
        if self._monitor is not None:
            self._monitor.join(5.0)
        with self._lock:
            proc = self.proc
        if proc is None:
            return None
        try:
            if proc.stdin is not None:
                proc.stdin.close()
        except OSError:
            pass
        for action in (None, signal.SIGTERM, signal.SIGKILL):
            if action is not None:
                log.warning("safety-nets child %d did not stop; sending %s", proc.pid, action.name)
                with contextlib.suppress(ProcessLookupError):
                    proc.send_signal(action)
            try:
                return proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                continue
        return proc.poll()

    def status(self) -> dict[str, Any]:
        """For the daemon's health: the child's pid, whether it runs, restarts, last exit code."""
        return {
            "pid": self.pid,
            "running": self.running,
            "restarts": self.restarts,
            "last_exit_code": self.last_exit_code,
        }
