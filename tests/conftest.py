"""Shared test fixtures: paths to the shared data, free loopback ports; the tier guard.

Tiers (markers registered in pyproject.toml): ``bus`` tests open real Zenoh sessions,
``slow`` tests take more than ~5 s or are long runs. ``make test-fast`` runs
``-m "not bus and not slow"``; ``make test`` runs every tier."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = PROJECT_ROOT.parent / "shared" / "data"


@pytest.fixture
def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="session")  # a path: module-scoped fixtures that simulate from it may use it
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is not present")
    return SHARED_DATA


@pytest.fixture(scope="session")
def demo_case():
    """(settings, simulation) of the default demo scenario, simulated once for the session
    (the restart-from-state and hot-standby tests feed engines from it)."""
    import tomllib

    from radar_fusion.config import settings_from_dict
    from radar_fusion.tools import simulate as sim

    scenario = sim.preset("demo")
    simulation = sim.simulate(scenario)
    return settings_from_dict(tomllib.loads(sim.config_toml(scenario))), simulation


@pytest.fixture(autouse=True)
def zenoh_sessions_only_in_bus_tests(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> None:
    """A test that opens a Zenoh session without the ``bus`` marker fails, saying so: the
    fast tier promises no bus. Every session of the service and the tools is opened by
    ``zenoh.open`` (``radar_fusion.bus.open_session`` calls it), which this replaces for an
    unmarked test. Not seen: module-scoped fixtures (they run first) and child processes;
    the modules that have those are marked ``bus`` as a whole."""
    if request.node.get_closest_marker("bus") is not None:
        return
    import zenoh

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError(f"{request.node.nodeid} opens a Zenoh session: mark it @pytest.mark.bus")

    monkeypatch.setattr(zenoh, "open", refuse)


@pytest.fixture(autouse=True)
def safety_nets_in_process_unless_tested(monkeypatch: pytest.MonkeyPatch) -> None:
    """Daemons built by tests run the safety nets on their processing thread, as one
    process ([safety_nets] process = in_process, through the environment override), so
    that each test does not start a child interpreter; the tests of the safety-nets
    process (test_safety_nets_process.py) ask for the child themselves."""
    monkeypatch.setenv("RADAR_FUSION_SAFETY_NETS__PROCESS", "in_process")


def pytest_configure(config):
    """One BLAS thread for the whole test session, as every radar-fusion entry point sets
    (cli.one_blas_thread): the engine's tiny matrices only contend on OpenBLAS threads."""
    from radar_fusion.cli import one_blas_thread

    one_blas_thread()
    # The IMM's numba kernels compiled (or loaded from their cache) before any test starts
    # a daemon in a child process: on a clean clone the first compilation takes ~10 s,
    # which would otherwise fall inside some test's wait for its daemon, in several
    # children at once.
    from radar_fusion.tracking.imm import IMMFilter

    IMMFilter()
