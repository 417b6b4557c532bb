"""`expoctl match` through its add_arguments/run functions."""

import argparse
import json

import numpy as np
import pytest
import skimage.data

from expoctl.features.match_cli import add_arguments, run
from expoctl.features.orb import OrbFrontEnd
from expoctl.features.pipeline import rgb_to_grey
from expoctl.io import write_png


def _parse(argv):
    parser = argparse.ArgumentParser(prog="expoctl match")
    add_arguments(parser)
    return parser.parse_args(argv)


@pytest.fixture
def pair(tmp_path):
    rgb = skimage.data.astronaut()
    write_png(rgb[20:260, 0:320], tmp_path / "prev.png")
    write_png(rgb[24:264, 6:326], tmp_path / "cur.png")
    return tmp_path / "prev.png", tmp_path / "cur.png", rgb


def test_prints_one_json_line_with_the_front_end_counts(pair, capsys):
    prev, cur, rgb = pair
    assert run(_parse([str(prev), str(cur)])) == 0
    out = capsys.readouterr().out
    assert out.count("\n") == 1
    result = json.loads(out)
    assert list(result) == ["n_features_prev", "n_features_cur", "n_matches", "n_inliers"]
    orb = OrbFrontEnd({})  # the CLI's defaults are the front end's defaults
    a, b = orb.extract(rgb_to_grey(rgb[20:260, 0:320])), orb.extract(rgb_to_grey(rgb[24:264, 6:326]))
    assert result == {"n_features_prev": orb.n_features(a), "n_features_cur": orb.n_features(b),
                      "n_matches": orb.match(a, b, 0)[0], "n_inliers": orb.match(a, b, 0)[1]}
    assert result["n_inliers"] > 200


def test_config_file_sets_front_end_parameters(pair, tmp_path, capsys):
    prev, cur, _ = pair
    (tmp_path / "f.yaml").write_text("features:\n  orb:\n    count_nfeatures: 123\n    match_nfeatures: 50\n")
    assert run(_parse(["--config", str(tmp_path / "f.yaml"), str(prev), str(cur)])) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["n_features_prev"] == 123 and result["n_matches"] <= 50


def test_unreadable_image_exits_2_with_a_message(pair, tmp_path, capsys):
    prev, _, _ = pair
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"\x89PNG garbage")
    assert run(_parse([str(prev), str(bad)])) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith("expoctl match: error: ") and "bad.png: unreadable" in captured.err
    assert "Traceback" not in captured.err
    assert run(_parse([str(prev), str(tmp_path / "nope.png")])) == 2
    assert "nope.png: image file missing" in capsys.readouterr().err


def test_size_mismatch_exits_2(pair, tmp_path, capsys):
    prev, _, _ = pair
    write_png(np.zeros((100, 100), np.uint8), tmp_path / "small.png")
    assert run(_parse([str(prev), str(tmp_path / "small.png")])) == 2
    err = capsys.readouterr().err
    assert "small.png: image is 100×100 but" in err and "320×240" in err


def test_bad_config_value_exits_2(pair, tmp_path, capsys):
    prev, cur, _ = pair
    (tmp_path / "f.yaml").write_text("orb:\n  count_nfeatures: -5\n")
    assert run(_parse(["--config", str(tmp_path / "f.yaml"), str(prev), str(cur)])) == 2
    assert "features.orb.count_nfeatures" in capsys.readouterr().err


def test_viso_front_end(pair, capsys):
    pytest.importorskip("expoctl.features.viso")
    prev, cur, _ = pair
    assert run(_parse(["--frontend", "viso", str(prev), str(cur)])) == 0
    result = json.loads(capsys.readouterr().out)
    assert 0 < result["n_inliers"] <= result["n_matches"]


def test_rejects_unknown_front_end():
    with pytest.raises(SystemExit):
        _parse(["--frontend", "sift", "a.png", "b.png"])
