"""City configs: packaged defaults, YAML files, and bad configs failing before any rendering, naming the key."""

from pathlib import Path

import pytest
import yaml

from expoctl.errors import ConfigError
from expoctl.world import load_city
from expoctl.world.cities import CITY_NAMES, city_config, packaged_city

CONF = Path(__file__).resolve().parents[2] / "conf" / "world" / "cities"


def test_unknown_city_lists_every_name_a_user_may_give():
    """The packaged cities, then the scenario cities that exist only as YAML in the city directory."""
    with pytest.raises(ConfigError) as exc:
        city_config("nowhere", CONF)
    assert exc.value.problems == [("world.city", "unknown city 'nowhere'; known cities: train, validation, test, "
                                   "stress, ramp_tunnel, underpass (or pass a dict)")]
    assert city_config("underpass", CONF)["name"] == "underpass"
    with pytest.raises(ConfigError, match="known cities: train, validation, test, stress [(]or pass a dict[)]"):
        city_config("underpass")  # without a city directory only the packaged cities exist


@pytest.mark.parametrize("name", CITY_NAMES)
def test_packaged_cities_validate_and_match_yaml(name):
    cfg = city_config(name)
    assert cfg["name"] == name
    assert city_config(name, CONF) == cfg  # conf/world/cities/<name>.yaml mirrors the packaged default


def test_validation_is_training_city_under_other_conditions():
    train, val, test = packaged_city("train"), packaged_city("validation"), packaged_city("test")
    for key in ("route", "road", "roadside", "tunnels", "lamps", "textures", "albedo", "seed"):
        assert val[key] == train[key]
    assert val["traversal"]["seed"] != train["traversal"]["seed"]
    assert val["traversal"]["sun_elevation_deg"] != train["traversal"]["sun_elevation_deg"]
    # test city: disjoint seeds, other photo crops, other tunnel structure
    assert test["seed"] != train["seed"] and test["textures"]["seed"] != train["textures"]["seed"]
    assert test["traversal"]["seed"] not in (train["traversal"]["seed"], val["traversal"]["seed"])
    assert test["textures"]["photo_crop"] != train["textures"]["photo_crop"]
    assert {t["profile"] for t in test["tunnels"]} != {t["profile"] for t in train["tunnels"]}
    assert all(70 <= t["length_m"] <= 90 for t in train["tunnels"]) and len(train["tunnels"]) == 2


def _bad(mutate):
    cfg = packaged_city("train")
    mutate(cfg)
    return cfg


@pytest.mark.parametrize("mutate, key", [
    (lambda c: c["route"]["pieces"][0].update(straight_m=-5.0), "world.city.route.pieces.0.straight_m"),
    (lambda c: c["route"]["pieces"][0].update(straight_m=300.0), "world.city.route.pieces"),  # no longer closes
    (lambda c: c["tunnels"][0].update(length_m=-80.0), "world.city.tunnels.0.length_m"),
    (lambda c: c["tunnels"][0].update(length_m=5000.0), "world.city.tunnels.0.length_m"),
    (lambda c: c["tunnels"][1].update(start_m=100.0), "world.city.tunnels.1.start_m"),  # overlaps tunnel 0
    (lambda c: c["tunnels"][0].update(profile="round"), "world.city.tunnels.0.profile"),
    (lambda c: c["traversal"].update(speed_kmh=[80.0, 40.0]), "world.city.traversal.speed_kmh"),
    (lambda c: c["traversal"].update(speed_kmh=[0.0, 0.0]), "world.city.traversal.speed_kmh"),
    (lambda c: c["roadside"].update(height_m=[20.0, 4.0]), "world.city.roadside.height_m"),
    (lambda c: c["lamps"].update(spacing_m=0.0), "world.city.lamps.spacing_m"),
    (lambda c: c["lighting"].pop("daylight_tail_m"), "world.city.lighting.daylight_tail_m"),
    (lambda c: c["traversal"].update(hdri={"path": "/nonexistent/sky.hdr", "median_cd_m2": 5000.0,
                                           "azimuth_deg": 0.0}), "world.city.traversal.hdri.path"),
])
def test_bad_configs_raise_naming_the_key(mutate, key):
    with pytest.raises(ConfigError) as err:
        load_city(_bad(mutate))
    assert err.value.key == key
    assert key in str(err.value)


def test_unknown_city_and_base_override(tmp_path):
    with pytest.raises(ConfigError, match="world.city"):
        load_city("atlantis")
    city = load_city({"base": "train", "name": "slow", "traversal": {"speed_kmh": [30.0, 31.0]}})
    assert city.name == "slow" and city.cfg["tunnels"] == packaged_city("train")["tunnels"]
    (tmp_path / "mine.yaml").write_text(yaml.safe_dump({"base": "test", "name": "mine"}))
    assert load_city("mine", city_dir=tmp_path).cfg["route"] == packaged_city("test")["route"]
    (tmp_path / "broken.yaml").write_text("- a list\n")
    with pytest.raises(ConfigError, match="world.city"):
        load_city("broken", city_dir=tmp_path)


def test_traversal_arguments_are_checked():
    city = load_city("train")
    with pytest.raises(ConfigError, match="world.traversal.fps"):
        city.traversal(0, 10, fps=0.0)
    with pytest.raises(ConfigError, match="world.traversal.n_frames"):
        city.traversal(0, 0)


def test_world_group_config():
    import yaml as _yaml

    from expoctl.world import load_world_city, validate_world_config
    world = _yaml.safe_load((CONF.parent / "default.yaml").read_text())
    world["city_dir"] = str(CONF)
    validate_world_config(world)
    assert load_world_city(world, "validation").name == "validation"
    with pytest.raises(ConfigError, match="world.cities.nowhere"):
        load_world_city(world, "nowhere")
    bad = dict(world, cities={"train": "atlantis"})
    with pytest.raises(ConfigError, match="world.city"):
        validate_world_config(bad)
    bad = dict(world, render=dict(world["render"], width=-3))
    with pytest.raises(ConfigError, match="world.render.width"):
        validate_world_config(bad)
