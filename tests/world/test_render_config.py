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
                                "colour": True})
    keys = [k for k, _ in exc.value.problems]
    assert keys == [f"world.render.{k}" for k in ("width", "height", "glare_fraction", "mip_bias", "tmax_m", "blur",
                                                  "max_subframes", "share_render", "backend", "colour")]
    assert exc.value.problems[4] == ("world.render.tmax_m", "must be a number > 10.0 m, got 10")


def test_with_size_keeps_the_rest():
    r = RenderConfig(hfov_deg=70.0, blur="reference").with_size(160, None)
    assert (r.width, r.height, r.hfov_deg, r.blur) == (160, 480, 70.0, "reference")
