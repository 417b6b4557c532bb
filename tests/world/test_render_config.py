"""`world.render`: one definition of its keys and bounds (RenderConfig), the defaults are conf/'s."""

from pathlib import Path

import pytest
import yaml

from expoctl.errors import ConfigError
from expoctl.world import RenderConfig, intrinsics

CONF = Path(__file__).resolve().parents[2] / "conf"


def test_defaults_are_the_configured_ones():
    render = yaml.safe_load((CONF / "world" / "default.yaml").read_text())["render"]
    assert RenderConfig.from_dict(render) == RenderConfig()
    assert RenderConfig.from_world({"render": render}) == RenderConfig()


@pytest.mark.parametrize("hfov", [1e-6, 59.1, 179.9])
def test_field_of_view_inside_the_pinhole_limits(hfov):
    assert RenderConfig.from_dict({"hfov_deg": hfov}).hfov_deg == hfov
    assert intrinsics(64, 48, hfov)[0, 0] > 0


@pytest.mark.parametrize("hfov", [0, 180, 200.0, -5])
def test_field_of_view_at_or_past_the_pinhole_limits(hfov):
    message = f"config key 'world.render.hfov_deg': must be a number in (0.0, 180.0) degrees, got {hfov!r}"
    with pytest.raises(ConfigError) as exc:
        RenderConfig.from_dict({"hfov_deg": hfov})
    assert str(exc.value) == message
    with pytest.raises(ConfigError) as exc:
        intrinsics(64, 48, hfov)
    assert str(exc.value) == message


def test_every_bad_key_reported_at_once():
    with pytest.raises(ConfigError) as exc:
        RenderConfig.from_dict({"width": 8, "height": 8193, "glare_fraction": 0.06, "mip_bias": 0, "tmax_m": 10,
                                "blur": "smudge", "max_subframes": 0, "share_render": 1, "backend": "vulkan",
                                "portal_daylight": "lightmap", "colour": True})
    keys = [k for k, _ in exc.value.problems]
    assert keys == [f"world.render.{k}" for k in ("width", "height", "glare_fraction", "mip_bias", "tmax_m", "blur",
                                                  "max_subframes", "share_render", "backend", "portal_daylight",
                                                  "colour")]
    assert exc.value.problems[4] == ("world.render.tmax_m", "must be a number > 10.0 m, got 10")


def test_with_size_keeps_the_rest():
    r = RenderConfig(hfov_deg=70.0, blur="reference").with_size(160, None)
    assert (r.width, r.height, r.hfov_deg, r.blur) == (160, 480, 70.0, "reference")


def test_portal_daylight_is_exact_unless_asked():
    assert RenderConfig().portal_daylight == "exact"
    assert RenderConfig.from_dict({"portal_daylight": "light_map"}).portal_daylight == "light_map"


def test_validated_checks_a_directly_built_config():
    assert RenderConfig(hfov_deg=70.0).validated() == RenderConfig(hfov_deg=70.0)
    with pytest.raises(ConfigError) as exc:
        RenderConfig(width=8, portal_daylight="approx").validated()
    assert [k for k, _ in exc.value.problems] == ["world.render.width", "world.render.portal_daylight"]


def test_renderer_defaults_are_render_configs():
    """One source of defaults (issue 44): a Renderer built without options has RenderConfig's field of view (59.1°,
    not the 70° its keyword defaults once had), size and options; a bad config is refused by the same check."""
    from expoctl.world import Renderer, load_city

    city = load_city("train")
    r = Renderer(city)
    assert r.config == RenderConfig()
    assert (r.width, r.height, r.hfov_deg) == (640, 480, 59.1)
    assert r.K[0, 0] == intrinsics(640, 480, 59.1)[0, 0]
    assert (r.glare_fraction, r.blur, r.max_subframes, r.share_render) == (0.005, "fast", 48, False)
    with pytest.raises(ConfigError, match="world.render.max_subframes"):
        Renderer(city, RenderConfig(max_subframes=0))
