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


def test_the_days_met_sets_the_mode_c_heights_error(tmp_path, monkeypatch):
    """Without the day's temperature a Mode C height carries 3 % of error, with it 1 % (QNH alone
    moves every level by one offset: still 3 %); mode_c_height_sigma_fraction overrides both;
    values no day has are refused."""
    s = load_settings(write(tmp_path, GOOD))
    assert s.tracking.mode_c_met() == (None, None) and s.tracking.mode_c_sigma_fraction() == 0.03
    monkeypatch.setenv("RADAR_FUSION_TRACKING__QNH_HPA", "1021")
    s = load_settings(write(tmp_path, GOOD))
    assert s.tracking.mode_c_met() == (None, 1021.0) and s.tracking.mode_c_sigma_fraction() == 0.03
    monkeypatch.setenv("RADAR_FUSION_TRACKING__TEMPERATURE_DEVIATION_K", "12")
    s = load_settings(write(tmp_path, GOOD))
    assert s.tracking.mode_c_met() == (12.0, 1021.0) and s.tracking.mode_c_sigma_fraction() == 0.01
    monkeypatch.delenv("RADAR_FUSION_TRACKING__TEMPERATURE_DEVIATION_K")
    monkeypatch.setenv("RADAR_FUSION_TRACKING__MODE_C_HEIGHT_SIGMA_FRACTION", "0.02")
    assert load_settings(write(tmp_path, GOOD)).tracking.mode_c_sigma_fraction() == 0.02
    for name, bad in (("QNH_HPA", "1021000"), ("TEMPERATURE_DEVIATION_K", "288")):  # Pa, not hPa; K, not ΔK
        monkeypatch.setenv(f"RADAR_FUSION_TRACKING__{name}", bad)
        with pytest.raises(ConfigError, match=name.lower()):
            load_settings(write(tmp_path, GOOD))
        monkeypatch.delenv(f"RADAR_FUSION_TRACKING__{name}")


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


@pytest.mark.parametrize(
    "change, says",
    [
        (("lat = 45.1\nlon = 16.1", "lat = 16.1\nlon = 45.1"), "km from the system centre"),  # swapped
        (("center_lat = 45.0", "center_lat = -45.0"), "km from the system centre"),  # a sign
        (("lat = 45.1", "lat = 90.0"), "radars.0.lat"),  # at a pole: the engine cannot place it
        (("\nperiod_s = 4.0", "\nperiod_s = 12.0"), "longer than the shortest rotation"),  # 4 s radars
        (("sigma_azimuth_deg = 0.1", "sigma_azimuth_deg = 0.0017"), "sigma_azimuth_deg"),  # radians
        (("rotation_period_s = 4.0", "rotation_period_s = 0.067"), "rotation_period_s"),  # minutes
        (("rotation_period_s = 4.0", "rotation_period_s = 4.0\nmax_range_m = 250"), "max_range_m"),  # NM
        (("rotation_period_s = 4.0", 'rotation_period_s = 4.0\n[metrics]\nlisten = "127.0.0.1:99999"'), "1 to 65535"),
    ],
)
def test_a_config_the_engine_could_not_use_is_refused_at_load(tmp_path, change, says):
    """Each of these started silently (tracks thousands of km off, STCA measuring on a plane
    far from its origin) or crashed after the start with a traceback, whose exit code
    systemd restarts ten times over (deploy's unit stops on 2 only)."""
    with pytest.raises(ConfigError, match=says):
        load_settings(write(tmp_path, GOOD.replace(*change)))


def test_a_config_that_cannot_be_read_or_an_environment_value_that_cannot_is_a_config_error(tmp_path, monkeypatch):
    with pytest.raises(ConfigError, match="cannot be read"):
        load_settings(tmp_path)  # a directory
    bad = tmp_path / "latin1.toml"
    bad.write_bytes(GOOD.replace("r1", "r\xe9").encode("latin-1"))
    with pytest.raises(ConfigError, match="not UTF-8"):
        load_settings(bad)
    too_many = GOOD + "".join(
        f'\n[[radars]]\nid = "x{k}"\nlat = 45.1\nlon = 16.1\nsigma_range_m = 60\nsigma_azimuth_deg = 0.1\n'
        "rotation_period_s = 4.0\n"
        for k in range(64)
    )
    with pytest.raises(ConfigError, match="radars"):
        load_settings(write(tmp_path, too_many))
    monkeypatch.setenv("RADAR_FUSION_SYSTEM__PERIOD_S", "abc")
    with pytest.raises(ConfigError, match="RADAR_FUSION_SYSTEM__PERIOD_S from the environment"):
        load_settings(write(tmp_path, GOOD))
    monkeypatch.delenv("RADAR_FUSION_SYSTEM__PERIOD_S")
    monkeypatch.setenv("RADAR_FUSION_RADARS", "[not json")
    with pytest.raises(ConfigError, match="RADAR_FUSION_RADARS"):
        load_settings(write(tmp_path, GOOD))


def test_serve_refuses_to_start_without_its_safety_nets_maps_or_a_writable_state_dir(tmp_path):
    """A missing areas file let serve start: its safety-nets child died at every start
    (restarted for ever), the tracks ran without STCA, APW and MSAW, and serve exited 0. A
    state directory that is a file failed every period's save. Both are now refused before
    the start; external safety nets are not asked for their maps."""
    import argparse

    from radar_fusion.cli import _serve_preflight

    path = write(tmp_path, GOOD + '\n[safety_nets]\nmsa_file = "missing-msa.geojson"\n')
    settings = load_settings(path)

    def args(**kw):
        return argparse.Namespace(**{"config": str(path), "safety_nets": None, "state_dir": None, **kw})

    assert "missing-msa.geojson" in (_serve_preflight(settings, args()) or "")
    assert _serve_preflight(settings, args(safety_nets="external")) is None
    good = load_settings(write(tmp_path, GOOD))
    a_file = tmp_path / "state-is-a-file"
    a_file.write_text("x")
    assert "cannot be written" in (_serve_preflight(good, args(state_dir=str(a_file))) or "")
    assert _serve_preflight(good, args(state_dir=str(tmp_path / "state"))) is None
