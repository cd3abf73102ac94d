"""Configuration: TOML loading, environment overrides, errors that name file and field."""

from __future__ import annotations

from pathlib import Path

import pytest

from radar_fusion.config import ConfigError, load_settings

ROOT = Path(__file__).resolve().parents[1]

GOOD = """
[system]
center_lat = 45.0
center_lon = 16.0
period_s = 4.0

[bus]
mode = "router"
listen = ["tcp/127.0.0.1:7447"]

[[radars]]
id = "r1"
lat = 45.1
lon = 16.1
sigma_range_m = 60
sigma_azimuth_deg = 0.1
rotation_period_s = 4.0
"""


def write(tmp_path, text):
    p = tmp_path / "fusion.toml"
    p.write_text(text)
    return p


def test_example_configs_load():
    for path in sorted((ROOT / "deploy").glob("*.toml")):
        s = load_settings(path)
        assert s.radars and s.system.period_s > 0


def test_good_file_and_defaults(tmp_path):
    s = load_settings(write(tmp_path, GOOD))
    assert s.bus.prefix == "atc" and s.radars[0].alt_m == 0.0
    assert s.tracking.fusion_method == "matrix" and s.outliers.enabled


def test_environment_overrides_the_file(tmp_path, monkeypatch):
    monkeypatch.setenv("RADAR_FUSION_BUS__MODE", "client")
    monkeypatch.setenv("RADAR_FUSION_SYSTEM__PERIOD_S", "2.5")
    s = load_settings(write(tmp_path, GOOD))
    assert s.bus.mode == "client" and s.system.period_s == 2.5 and s.system.center_lat == 45.0


@pytest.mark.parametrize(
    "change, field",
    [
        (("center_lat = 45.0", "center_lat = 145.0"), "system.center_lat"),
        (('mode = "router"', 'mode = "hub"'), "bus.mode"),
        (("sigma_range_m = 60", "sigma_range_m = -1"), "radars.0.sigma_range_m"),
        (("rotation_period_s = 4.0", "rotation_period_s = 4.0\ncolour = 3"), "radars.0.colour"),
        (('id = "r1"', 'id = "r 1"'), "radars.0.id"),
    ],
)
def test_errors_name_the_file_and_the_field(tmp_path, change, field):
    path = write(tmp_path, GOOD.replace(*change))
    with pytest.raises(ConfigError) as err:
        load_settings(path)
    assert str(path) in str(err.value) and field in str(err.value)


def test_duplicate_radar_ids_refused(tmp_path):
    text = GOOD + GOOD[GOOD.index("[[radars]]") :]
    with pytest.raises(ConfigError, match="unique"):
        load_settings(write(tmp_path, text))


def test_a_pair_of_peers_must_be_reachable(tmp_path):
    """Zenoh routers do not relay between peers: a pair's peer with no listen endpoint
    never sees the other's election tokens, and both would publish (seen in a trial run)."""
    pair = "\n[redundancy]\nenabled = true\n"
    peer_unreachable = GOOD.replace('mode = "router"\nlisten = ["tcp/127.0.0.1:7447"]', 'mode = "peer"\nlisten = []')
    with pytest.raises(ConfigError, match="listen endpoints"):
        load_settings(write(tmp_path, peer_unreachable + pair))
    assert load_settings(write(tmp_path, peer_unreachable)).bus.mode == "peer"  # alone: fine
    peer = GOOD.replace('mode = "router"', 'mode = "peer"')
    assert load_settings(write(tmp_path, peer + pair)).redundancy.enabled
    client = GOOD.replace('mode = "router"\nlisten = ["tcp/127.0.0.1:7447"]', 'mode = "client"\nlisten = []')
    assert load_settings(write(tmp_path, client + pair)).redundancy.enabled


def test_missing_and_invalid_files(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_settings(tmp_path / "nope.toml")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_settings(write(tmp_path, "[system\n"))


def test_safety_net_section_is_validated_with_file_and_field(tmp_path):
    path = write(tmp_path, GOOD + "\n[safety_nets]\nlook_ahead_s = -5\n")
    with pytest.raises(ConfigError) as err:
        load_settings(path)
    assert str(path) in str(err.value) and "safety_nets.look_ahead_s" in str(err.value)
