from __future__ import annotations

import numpy as np
import pytest

from expoctl.camera.response import Response, linear_to_8bit, uint8_to_linear


@pytest.mark.parametrize("curve", ["srgb", "gamma", "linear"])
def test_round_trip_every_code(curve):
    r = Response(curve)
    codes = np.arange(256, dtype=np.uint8)
    np.testing.assert_array_equal(r.linear_to_8bit(r.uint8_to_linear(codes)), codes)


def test_srgb_known_values():
    assert linear_to_8bit(np.array([0.0, 1.0, 0.18])).tolist() == [0, 255, 118]  # 18 % grey → sRGB 118
    assert uint8_to_linear(np.array([255], np.uint8))[0] == pytest.approx(1.0)
    assert uint8_to_linear(np.array([118], np.uint8))[0] == pytest.approx(0.18, abs=0.002)


def test_monotone_and_clipped():
    out = linear_to_8bit(np.linspace(-0.5, 1.5, 1001))
    assert np.all(np.diff(out.astype(int)) >= 0) and out[0] == 0 and out[-1] == 255


# --------------------------------------------------------------------------- per-channel response (R, G, B)

PER_CHANNEL = dict(curve="gamma", gamma=(2.65, 2.12, 2.20), pedestal=(-0.10, -0.03, 0.02),
                   white_balance=(1.02, 1.22, 1.0))


def test_per_channel_round_trip_every_code():
    """Each channel decodes every code to its own linear value and re-encodes it to the same code; codes below a
    positive pedestal (blue: 0.02·255 = 5.1) are never delivered and decode to black."""
    r = Response(**PER_CHANNEL)
    codes = np.repeat(np.arange(256, dtype=np.uint8)[:, None], 3, axis=1)
    lin = r.uint8_to_linear(codes)
    delivered = codes >= np.array([0, 0, 5])
    np.testing.assert_array_equal(r.linear_to_8bit(lin)[delivered], codes[delivered])
    assert np.all(lin[:5, 2] == 0) and not np.array_equal(lin[:, 0], lin[:, 1])


def test_per_channel_known_values():
    """code/255 = p + (1 − p)·(wb·x)^(1/γ) per channel: black gives the pedestal (0 if negative), x = 1/wb reaches
    255, and a channel whose white balance pushes it past full scale clips there."""
    r = Response(**PER_CHANNEL)
    assert r.linear_to_8bit(np.zeros(3)).tolist() == [0, 0, round(255 * 0.02)]
    x = 0.3
    expect = [round(255 * (p + (1 - p) * (wb * x) ** (1 / g)))
              for g, p, wb in zip(PER_CHANNEL["gamma"], PER_CHANNEL["pedestal"], PER_CHANNEL["white_balance"])]
    assert r.linear_to_8bit(np.full(3, x)).tolist() == expect
    assert r.linear_to_8bit(np.full(3, 1 / 1.22)).tolist()[1] == 255 and r.linear_to_8bit(np.ones(3)).tolist() == [255] * 3


def test_uniform_parameters_are_the_scalar_curve_and_accept_any_shape():
    """Equal channels (the default) give exactly the scalar curve's values on any array shape."""
    r = Response("gamma", (2.2, 2.2, 2.2), (0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    assert not r.per_channel
    x = np.linspace(0, 1, 101)
    np.testing.assert_array_equal(r.linear_to_8bit(x), Response("gamma", 2.2).linear_to_8bit(x))
    assert not Response("srgb", (1.0, 2.0, 3.0)).per_channel  # gamma is not part of the sRGB curve


def test_per_channel_needs_rgb_input():
    r = Response(**PER_CHANNEL)
    with pytest.raises(ValueError, match="last axis of 3"):
        r.linear_to_8bit(np.linspace(0, 1, 10))
    with pytest.raises(ValueError, match="last axis of 3"):
        r.uint8_to_linear(np.zeros((4, 4), np.uint8))


@pytest.mark.parametrize("d,key", [
    ({"response_curve": "log"}, "s.response_curve"),
    ({"response_gamma": 0}, "s.response_gamma"),
    ({"response_curve": "gamma", "response_gamma_rgb": [2.2, 2.2]}, "s.response_gamma_rgb"),
    ({"response_gamma_rgb": [2.2, -1.0, 2.2]}, "s.response_gamma_rgb"),
    ({"response_pedestal_rgb": [0.0, 1.0, 0.0]}, "s.response_pedestal_rgb"),
    ({"white_balance_rgb": [1.0, 0.0, 1.0]}, "s.white_balance_rgb"),
    ({"white_balance_rgb": [1.0, float("nan"), 1.0]}, "s.white_balance_rgb"),
    ({"white_balance_rgb": 1.0}, "s.white_balance_rgb")])
def test_bad_response_config_names_the_key(d, key):
    from expoctl.camera.response import response_from_config
    from expoctl.errors import ConfigError

    with pytest.raises(ConfigError) as exc:
        response_from_config(d, "s")
    assert exc.value.key == key
