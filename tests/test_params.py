"""Bad parameter files stop with an error naming the file, the key and the allowed range."""
import pytest

from alight.diagrams.cli import main
from alight.diagrams.world.sim_vehicle import SimVehicleConfig, load_sim_vehicle_config
from alight.systems.params import ConfigError, load_params
from alight.systems.plant.hexacopter import load_hexacopter_params


def test_shipped_files_load():
    config = load_sim_vehicle_config()
    assert config.flight_controller.period == 0.004
    assert len(load_hexacopter_params().rotors) == 6


def test_out_of_range_value_names_file_key_and_range(tmp_path):
    bad = tmp_path / "vehicle.yaml"
    bad.write_text("imu:\n  period: -0.005\n")
    with pytest.raises(ConfigError) as error:
        load_params(SimVehicleConfig, bad)
    message = str(error.value)
    assert str(bad) in message and "imu.period" in message and "[0.0005, 0.1]" in message


def test_unknown_key_is_refused(tmp_path):
    bad = tmp_path / "vehicle.yaml"
    bad.write_text("flight_controller:\n  commander:\n    stale_timout: 0.5\n")
    with pytest.raises(ConfigError, match="stale_timout"):
        load_params(SimVehicleConfig, bad)


@pytest.mark.parametrize("text, key", [
    ("wind:\n  mean_speed: .nan\n", "wind.mean_speed"),
    ("initial_position: [0.0, 1.0, 2.0]\n", "initial_position"),
    ("flight_controller:\n  rate:\n    kp: [1.0, 2.0]\n", "flight_controller.rate.kp"),
])
def test_non_finite_or_wrong_length_values_are_refused(tmp_path, text, key):
    bad = tmp_path / "vehicle.yaml"
    bad.write_text(text)
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        load_params(SimVehicleConfig, bad)


def test_missing_file_and_malformed_yaml(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_params(SimVehicleConfig, tmp_path / "nope.yaml")
    bad = tmp_path / "broken.yaml"
    bad.write_text("imu: [period: 0.1\n")
    with pytest.raises(ConfigError, match="broken.yaml"):
        load_params(SimVehicleConfig, bad)


def test_vehicle_with_too_few_rotors_is_refused(tmp_path):
    bad = tmp_path / "tri.yaml"
    bad.write_text("rotors:\n  - {name: a, xyz: [0.2, 0, 0], spin: cw}\n")
    with pytest.raises(ConfigError, match="at least 4 rotors"):
        load_hexacopter_params(str(bad))


def test_cli_reports_config_errors_without_a_traceback(tmp_path, capsys):
    bad = tmp_path / "vehicle.yaml"
    bad.write_text("time_step: 5.0\n")
    assert main(["hover", "--config", str(bad)]) == 2
    assert "time_step" in capsys.readouterr().err
    assert main(["hover", "--wind", "500"]) == 2
    assert "wind.mean_speed" in capsys.readouterr().err
