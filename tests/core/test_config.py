import dataclasses
import tomllib

import pytest

from core.config import DEFAULT_CONFIG_PATH, Config, load_config, model_for_camera, parse_override
from core.errors import ConfigError


def test_config_toml_documents_exactly_the_defaults():
    table = tomllib.loads(DEFAULT_CONFIG_PATH.read_text())
    defaults = Config()
    for section in dataclasses.fields(Config):
        if section.name == "rules":  # [[rules]]: none by default (config.toml shows one commented out)
            assert "rules" not in table and defaults.rules == []
            continue
        values = dataclasses.asdict(getattr(defaults, section.name))
        assert table.get(section.name) == values, f"[{section.name}] in config.toml differs from the dataclass"


def test_rules_are_an_array_of_tables_with_class_spelled_class(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text('[[rules]]\nname = "tall"\nclass = "vehicle"\nmin_height_m = 3\n'
                    'zone = [[0, 0], [10, 0], [10, 10]]\n\n[[rules]]\nname = "any"\n')
    rules = load_config(path).rules
    assert [(r.name, r.cls, r.min_height_m) for r in rules] == [("tall", "vehicle", 3.0), ("any", "", 0.0)]
    assert rules[0].zone == [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]]
    path.write_text('[[rules]]\nname = "x"\nmin_hieght_m = 3\n')
    with pytest.raises(ConfigError, match="unknown key 'min_hieght_m' in \\[\\[rules\\]\\] #1"):
        load_config(path)
    path.write_text('[rules]\nname = "x"\n')
    with pytest.raises(ConfigError, match="array of tables"):
        load_config(path)


def test_unknown_key_is_rejected(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[tracking]\nmin_hitz = 3\n")
    with pytest.raises(ConfigError, match="unknown config key 'tracking.min_hitz'"):
        load_config(path)


def test_unknown_section_is_rejected(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[trackin]\nmin_hits = 3\n")
    with pytest.raises(ConfigError, match=r"unknown config section \[trackin\]"):
        load_config(path)


def test_wrong_type_is_rejected(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text('[tracking]\nmin_hits = "three"\n')
    with pytest.raises(ConfigError, match="tracking.min_hits .* must be int"):
        load_config(path)


def test_int_widens_to_float_but_bool_is_not_int(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[camera]\nheight_m = 7\n")
    assert load_config(path).camera.height_m == 7.0
    path.write_text("[tracking]\nmin_hits = true\n")
    with pytest.raises(ConfigError):
        load_config(path)


def test_overrides_win_and_parse_toml_values():
    config = load_config(None, ["tracking.min_hits=7", "objects.background=cnt", "output.mcap=false"])
    assert config.tracking.min_hits == 7
    assert config.objects.background == "cnt"
    assert config.output.mcap is False
    with pytest.raises(ConfigError):
        parse_override("min_hits=7")


@pytest.mark.parametrize("key", ["min_area_px", "background", "height_measurement_noise_m"])
def test_a_moved_key_says_where_it_is_now(tmp_path, key):
    path = tmp_path / "c.toml"
    path.write_text(f"[tracking]\n{key} = 1\n")
    with pytest.raises(ConfigError, match=rf"'tracking.{key}' .* has moved: it is 'objects.{key}' now"):
        load_config(path)
    with pytest.raises(ConfigError, match=rf"it is 'objects.{key}' now"):
        load_config(None, [f"tracking.{key}=1"])


def test_missing_config_file(tmp_path):
    with pytest.raises(ConfigError, match="config file not found"):
        load_config(tmp_path / "nope.toml")


@pytest.mark.parametrize("model, camera, expected", [
    ("", {}, ("", "blobs")),                                              # nothing known: v1 (an assumed height)
    ("", {"height_m": 6.4}, ("v2", "network")),                           # the camera height only: v2's case
    ("", {"height_m": 6.4, "pitch_deg": 20.0}, ("", "blobs")),            # a full pose: v1 and blobs
    ("", {"height_m": 6.4, "calibration": "cam.json"}, ("", "blobs")),    # a calibration file
    ("v1", {"height_m": 6.4}, ("v1", "blobs")),                           # a named model is used as named
    ("int8", {"height_m": 6.4}, ("int8", "blobs")),
])
def test_the_default_model_follows_what_the_run_knows_of_its_camera(model, camera, expected):
    config = Config()
    config.height.model = model
    for key, value in camera.items():
        setattr(config.camera, key, value)
    chosen = model_for_camera(config)
    assert (chosen.height.model, chosen.objects.source) == expected
    assert (config.height.model, config.objects.source) == (model, "blobs")   # the given config is not changed
