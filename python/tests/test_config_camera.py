"""Config and Camera: construction, overrides, round trips and the errors they raise."""

import json

import pytest

import dynapix
from dynapix import Camera, Config, ConfigError, DynapixError


def test_defaults_are_the_papers_dynapix():
    c = Config()
    assert c.method == "dynapix"
    assert c.mode == "paper"
    d = c.to_dict()
    assert d["method"] == "dynapix" and "motion" in d and "slam" in d
    assert Config(d) == c


def test_dict_file_and_keyword_overrides(tmp_path):
    c = Config({"method": "orbslam2"}, slam__seed=7)
    assert c.method == "orbslam2" and c.seed == 7
    assert c.to_dict()["slam"]["seed"] == 7
    j = tmp_path / "c.json"
    j.write_text(json.dumps({"mode": "reference"}))
    assert Config(str(j)).mode == "reference"
    assert Config.from_file(j, method="orbslam2").method == "orbslam2"
    y = tmp_path / "c.yaml"
    y.write_text("method: orbslam2\nslam:\n  seed: 3\n")
    cy = Config.from_file(y)
    assert (cy.method, cy.seed) == ("orbslam2", 3)
    assert Config.from_yaml("method: orbslam2").method == "orbslam2"
    assert Config.from_json('{"slam": {"seed": 2}}').seed == 2
    r = c.replace(method="dynapix")
    assert r.method == "dynapix" and r.seed == 7 and c.method == "orbslam2"


def test_unknown_keys_and_bad_values_raise_config_error_naming_them(tmp_path):
    with pytest.raises(ConfigError, match="no_such_key"):
        Config({"no_such_key": 1})
    with pytest.raises(ConfigError, match="bogus"):
        Config(slam__bogus=1)
    with pytest.raises(ConfigError, match="method"):
        Config(method="not-a-method")
    with pytest.raises(ConfigError):
        Config(42)
    bad = tmp_path / "bad.yaml"
    bad.write_text("slam: [1, 2\n")
    with pytest.raises(ConfigError, match="bad.yaml"):
        Config.from_file(bad)
    with pytest.raises(ConfigError, match="missing.yaml"):
        Config.from_file(tmp_path / "missing.yaml")
    assert issubclass(ConfigError, DynapixError)


def test_camera_presets_values_and_settings_files(tmp_path):
    tum1 = Camera.preset("tum1")
    assert (tum1.width, tum1.height) == (640, 480)
    assert tum1.dist[0] != 0.0  # fr1 is distorted
    assert Camera.preset("BONN").depth_factor == 5000.0
    with pytest.raises(ConfigError, match="tum9"):
        Camera.preset("tum9")
    f = tmp_path / "cam.yaml"
    f.write_text(tum1.to_yaml())
    assert Camera.from_settings(f) == tum1
    c = Camera(300.0, 300.0, 160.0, 120.0, 320, 240, depth_factor=1000.0)
    assert (c.width, c.height, c.depth_factor, c.fx) == (320, 240, 1000.0, 300.0)
    assert c.to_dict()["pinhole"]["fx"] == 300.0
    with pytest.raises(ConfigError):
        Camera(-1.0, 300.0, 160.0, 120.0, 320, 240)
    with pytest.raises(dynapix.IoError):
        Camera.from_settings(tmp_path / "none.yaml")


def test_docstrings_everywhere():
    for name in dynapix.__all__:
        obj = getattr(dynapix, name)
        if callable(obj):
            assert obj.__doc__, f"{name} has no docstring"
    for cls in (Config, Camera, dynapix.Online, dynapix.RunResult, dynapix.Sequence):
        for attr, member in vars(cls).items():
            if not attr.startswith("_") and callable(member):
                assert member.__doc__, f"{cls.__name__}.{attr} has no docstring"
