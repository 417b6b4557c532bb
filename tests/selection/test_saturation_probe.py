"""The saturation probe: config validation, start frames, and closed-loop runs whose outcome physics fixes — AG+AE
returns to its own level from +6 EV, a camera stuck at 30 ms and 30 dB ends white and fails."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from expoctl.errors import ConfigError, InputError
from expoctl.selection.saturation_probe import ProbeConfig, _longest_run, settings_at, start_frames, summary_line


@pytest.mark.parametrize("d,key", [
    ({"frames": 1}, "p.frames"), ({"frames": 10, "last_frames": 10}, "p.last_frames"),
    ({"offsets_ev": []}, "p.offsets_ev"), ({"offsets_ev": [0, float("nan")]}, "p.offsets_ev"),
    ({"max_saturated_fraction": 0}, "p.max_saturated_fraction"), ({"max_saturated_fraction": 1.5},
                                                                     "p.max_saturated_fraction"),
    ({"max_dark_fraction": 0}, "p.max_dark_fraction"), ({"max_dark_fraction": 1.01}, "p.max_dark_fraction"),
    ({"enabled": "yes"}, "p.enabled"), ({"city": ""}, "p.city"), ({"width": 8}, "p.width"),
    ({"traversal": -1}, "p.traversal"), ({"offset": [0]}, "p.offset")])
def test_bad_probe_config_names_the_key(d, key):
    with pytest.raises(ConfigError) as exc:
        ProbeConfig.from_dict(d, "p")
    assert exc.value.key == key


def test_probe_config_defaults_and_lists():
    p = ProbeConfig.from_dict({"offsets_ev": [0, 6]}, "p")
    assert p == ProbeConfig() and p.offsets_ev == (0.0, 6.0) and ProbeConfig.from_dict(None, "p") == p
    assert ProbeConfig.from_dict({"max_dark_fraction": None}, "p").max_dark_fraction is None


def test_select_config_refuses_a_probe_on_the_held_out_city():
    from expoctl.selection.model_selection import SelectConfig

    with pytest.raises(ConfigError) as exc:
        SelectConfig.from_dict({"probe": {"city": "test"}})
    assert exc.value.key == "select_model.probe.city"


def test_longest_run():
    assert _longest_run(np.array([0, 1, 1, 0, 1, 1, 1, 0], bool)) == (4, 3)
    assert _longest_run(np.array([1, 1, 0, 1, 1], bool)) == (0, 2)  # first on a tie
    assert _longest_run(np.zeros(4, bool)) == (0, 0)


def _trajectory(sections, portals, fps=10.0):
    return SimpleNamespace(frame_section=sections, portal_times_s=portals, fps=fps)


def test_start_frames_centre_each_run_in_the_longest_stretch():
    """10 fps; entry at 1.0 s, exit at 3.0 s: frames 10–29 are inside the tunnel (20 frames, static or not). Static
    outside: 0–9 and 34–63 (the longer, 30 frames). Runs of 4 frames start 13 into the open road, 8 into the tunnel."""
    sections = ["static"] * 10 + ["dynamic"] * 2 + ["static"] * 16 + ["dynamic"] * 6 + ["static"] * 30
    traj = _trajectory(sections, [(1.0, 0, "entry"), (3.0, 0, "exit")])
    assert start_frames(traj, 4) == {"open_road": 34 + 13, "tunnel": 10 + 8}
    with pytest.raises(InputError, match="longest tunnel stretch of the traversal has 20 frames"):
        start_frames(traj, 21)


def test_settings_at_is_the_inverse_of_the_exposure_value():
    from expoctl.camera.ranges import exposure_value_ev

    for ev in (-12.0, -7.5, -4.0):  # 244 µs, 5.5 ms, 30 ms + 6 dB (exposure first, then gain)
        s = settings_at(ev)
        assert float(exposure_value_ev(s.gain_db, s.exposure_us)) == pytest.approx(ev, abs=1e-9)
    assert settings_at(-4.0).exposure_us == pytest.approx(30000.0)


@pytest.fixture(scope="module")
def probe(tmp_path_factory):
    from eval_fixtures import make_fixture_project

    from expoctl.evaluation.inputs import EvaluationInputs
    from expoctl.selection.saturation_probe import make_probe

    root = tmp_path_factory.mktemp("probe")
    cfg = make_fixture_project(root)
    # 48 frames: the fitted AG+AE darkens by at most 0.178 EV per frame, so +6 EV takes ≥ 34 frames, then the last
    # ~2.5 EV (seen unsaturated) decay by 0.873 per frame; more frames would carry the tunnel start out of the exit
    pcfg = ProbeConfig.from_dict({"frames": 48, "width": 64, "height": 48, "first_frames": 4, "last_frames": 4}, "p")
    cfg["world"]["cities"]["train"] = {"base": "train", "textures": {"tile_px": 256}}
    inputs = EvaluationInputs.from_resolved(cfg)
    return make_probe(pcfg, inputs.world, inputs.rig, inputs.sensor, inputs.controller_config("agae"), root), cfg


def test_agae_returns_to_its_own_level_from_a_bright_start(probe):
    """AG+AE is the reference: from its level it stays there, and from +6 EV (0.178 EV per frame at most, the real
    camera's rate) it is back within a fraction of an EV in 48 frames, with nothing clipped in the tunnel; so it
    passes."""
    from expoctl.controllers.registry import make_controller

    p, cfg = probe
    result = p.run(make_controller("agae", (cfg.get("controllers") or {}).get("agae", {})))
    for start, rows in result["starts"].items():
        at_level, bright = rows
        assert abs(at_level["final_offset_ev"]) < 0.1, start
        assert abs(bright["final_offset_ev"]) < 0.3
        # +6 EV, unless the camera's range ends first: here the tunnel's own level is 5.7 EV below the top (30 ms at
        # 30 dB), so that start is clipped a little short of 6 EV
        assert 5.0 < bright["start_offset_ev"] <= 6.0 + 1e-9
        # the darkening limit sets the pace; the first of the 4 frames has no step yet (the AE meters the frame before)
        assert bright["mean_step_first_ev"] == pytest.approx(-0.178 * 3 / 4, abs=1e-3), start
    assert result["passes"] and result["worst_saturated_frac"] < 0.5 and result["worst_dark_frac"] < 0.5


def test_a_camera_stuck_at_the_longest_exposure_and_highest_gain_fails(probe):
    from expoctl.controllers.registry import make_controller

    p, _ = probe
    stuck = make_controller("fixed", {"mode": "manual", "gain_db": 30.0, "exposure_us": 30000.0})
    result = p.run(stuck)
    assert not result["passes"] and result["worst_saturated_frac"] == 1.0 and result["fails_on"] == ["white"]
    assert all(r["final_saturated_frac"] == 1.0 for r in result["starts"]["open_road"])
    assert summary_line("stuck", result).endswith("FAILS (white fixed point)")


def test_a_camera_stuck_at_the_shortest_exposure_and_lowest_gain_fails_on_the_dark_side(probe):
    """The mirror image. In the tunnel AG+AE settles at about −5.7 EV; 75 µs at 0 dB is −13.7 EV, 8 EV darker, so a
    pixel keeps 1/256 of its light: everything AG+AE shows below about 168 of 255 (sRGB) falls to ≤ 5 codes, which
    in a tunnel is most of the frame (AG+AE's own frame there has no black pixel). With a dark line at half the
    frame it fails with nothing clipped white; with the dark line off (None) it passes, as the white-only probe did."""
    from dataclasses import replace

    from expoctl.camera.ranges import EXPOSURE_US_MIN, GAIN_DB_MIN
    from expoctl.controllers.registry import make_controller

    p, _ = probe
    stuck = {"mode": "manual", "gain_db": GAIN_DB_MIN, "exposure_us": EXPOSURE_US_MIN}
    saved = p.cfg
    try:
        p.cfg = replace(saved, max_dark_fraction=0.5)
        result = p.run(make_controller("fixed", stuck))
        assert all(r["final_offset_ev"] < -7.5 and r["final_dark_frac"] > 0.5 for r in result["starts"]["tunnel"])
        assert result["worst_saturated_frac"] == 0.0 and not result["passes"] and result["fails_on"] == ["black"]
        black = f"{100 * result['worst_dark_frac']:.0f} % black"
        assert summary_line("stuck", result).endswith(f"worst 0 % white, {black}: FAILS (black fixed point)")
        p.cfg = replace(saved, max_dark_fraction=None)
        result = p.run(make_controller("fixed", stuck))
        assert result["passes"] and result["fails_on"] == []
        assert summary_line("stuck", result).endswith(": passes")
    finally:
        p.cfg = saved


@pytest.mark.slow  # two spawned workers each build the probe (city, AG+AE reference) and a network
def test_probe_candidates_in_worker_processes_equal_in_process(probe, tmp_path):
    """probe_candidates fans the candidates out (expoctl.parallel): each worker builds its own probe and network, and
    the results are those of one probe run in this process, candidate after candidate, in candidate order."""
    import dataclasses
    import shutil
    from pathlib import Path

    from expoctl.evaluation.inputs import EvaluationInputs
    from expoctl.parallel import INPROCESS, ParallelConfig
    from expoctl.selection.model_selection import Candidate, probe_candidates

    p, cfg = probe
    # the fixture project's checkpoint (the `probe` fixture's directory beside this test's tmp_path)
    model = next(Path(tmp_path).parent.glob("probe*/models/controller.pt"), None)
    assert model is not None
    second = tmp_path / "controller2.pt"
    shutil.copy(model, second)
    cands = [Candidate("iteration1", 1, model), Candidate("iteration2", 2, second)]
    inputs = EvaluationInputs.from_resolved(cfg)
    pcfg = dataclasses.replace(p.cfg, offsets_ev=(6.0,))
    here = probe_candidates(inputs, cands, model.parents[1], pcfg, INPROCESS)
    workers = probe_candidates(inputs, cands, model.parents[1], pcfg, ParallelConfig("processes", n_jobs=2))
    assert list(workers) == ["iteration1", "iteration2"] and workers == here
    assert here["iteration1"] == here["iteration2"]  # the same network, so the same verdict
