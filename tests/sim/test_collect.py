import copy

import pandas as pd
import pytest
import yaml

from expoctl.errors import ConfigError
from expoctl.sim.closed_loop import RigConfig
from expoctl.sim.collect import CollectConfig, CollectInputs, collect, plan_sequences
from expoctl.raw.validate import validate_raw_dir
from expoctl.sim.protocol import perturb, PerturbationConfig
from expoctl.controllers.base import Settings

TINY = {
    "seed": 3,
    "rig": {"baseline_m": 0.0392, "fps": 15.0},
    # a cheap city: the train city with small texture tiles (atlas in ~1 s instead of ~10 s), from a city_dir file
    "world": {"cities": {"train": "small", "validation": "small", "test": "small"}, "city_dir": None,
              "render": {"width": 64, "height": 48, "hfov_deg": 70.0}},
    "collect": {
        "reference_controller": "agae",
        "initial_gain_db": 0.0,
        "initial_exposure_us": 5000.0,
        "warmup_frames": 2,
        "sensor_randomisation": 0.15,
        "splits": {
            "train": {"first_traversal": 0, "n_sequences": 1, "frames": 6},
            "validation": {"first_traversal": 5, "n_sequences": 1, "frames": 5},
            "test": None,
        },
    },
    "controllers": {"agae": {"damping": 0.2}},
}


@pytest.fixture(scope="module")
def city_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("cities")
    (d / "small.yaml").write_text(yaml.safe_dump({"base": "train", "name": "small", "textures": {"tile_px": 256}}))
    return str(d)


def tiny(city_dir):
    cfg = copy.deepcopy(TINY)
    cfg["world"]["city_dir"] = city_dir
    return cfg


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory, city_dir):
    out = tmp_path_factory.mktemp("raw") / "raw"
    summaries = collect(CollectInputs.from_resolved(tiny(city_dir)), out, progress=False)
    return out, summaries


def test_tiny_collect_is_valid_raw_data(tiny_run):
    out, summaries = tiny_run
    assert validate_raw_dir(out) == []
    assert [s["sequence"] for s in summaries] == ["train-small-t000", "validation-small-t005"]
    seq = out / "train" / "train-small-t000"
    meta = yaml.safe_load((seq / "sequence.yaml").read_text())
    assert meta["source"] == "sim" and meta["world"] == "small" and meta["split"] == "train"
    assert meta["rig"]["resolution"] == [64, 48] and meta["rig"]["baseline_m"] == 0.0392
    assert meta["reference_controller"]["name"] == "agae"
    assert meta["reference_controller"]["params"] == {"damping": 0.2}
    assert meta["sensor"]  # the randomised sensor parameters are logged
    # the world places the window around a portal crossing, and sections cover every recorded frame once
    covered = [f for s in meta["sections"] for f in range(s["start_frame"], s["end_frame"] + 1)]
    assert covered == list(range(6))
    frames = pd.read_csv(seq / "frames.csv")
    assert len(frames) == 12 and sorted(frames.camera.unique()) == [1, 2]
    # camera 2 is camera 1 perturbed, frame by frame (quadrant cycle over the traversal's frame index)
    cam1 = frames[frames.camera == 1].set_index("frame_id")
    cam2 = frames[frames.camera == 2].set_index("frame_id")
    cfg = PerturbationConfig()
    for fid in cam1.index:
        s1 = Settings(cam1.gain_db[fid], cam1.exposure_us[fid])
        s2 = perturb(s1, fid + meta["warmup_frames"], meta["seed"], cfg)
        assert cam2.gain_db[fid] == pytest.approx(s2.gain_db) and cam2.exposure_us[fid] == pytest.approx(s2.exposure_us)
    assert (cam1.timestamp_ns.to_numpy() == cam2.timestamp_ns.to_numpy()).all()  # synchronised


def test_collect_is_deterministic_per_seed(tiny_run, tmp_path, city_dir):
    out, _ = tiny_run
    cfg = tiny(city_dir)
    cfg["collect"]["splits"]["validation"] = None
    again = tmp_path / "again"
    collect(CollectInputs.from_resolved(cfg), again, progress=False)
    a, b = out / "train" / "train-small-t000", again / "train" / "train-small-t000"
    assert (a / "frames.csv").read_text() == (b / "frames.csv").read_text()
    assert (a / "sequence.yaml").read_text() == (b / "sequence.yaml").read_text()
    for p in sorted((a / "cam2").iterdir()):
        assert p.read_bytes() == (b / "cam2" / p.name).read_bytes()
    cfg["seed"] = 4
    other = tmp_path / "other"
    collect(CollectInputs.from_resolved(cfg), other, progress=False)
    assert (other / "train" / "train-small-t000" / "frames.csv").read_text() != (a / "frames.csv").read_text()


def _progress_counts(lines: list[str]) -> dict[str, list[tuple[int, int]]]:
    """(done, total) of every in-sequence progress line, per sequence."""
    import re

    out: dict[str, list[tuple[int, int]]] = {}
    for line in lines:
        m = re.fullmatch(r"(\S+): (\d+)/(\d+) frame pairs, \d+ s, [\d.]+ frame pairs/s", line)
        if m:
            out.setdefault(m[1], []).append((int(m[2]), int(m[3])))
    return out


def test_progress_lines_while_a_sequence_renders(tiny_run, tmp_path, city_dir):
    """Under DVC (a logger as `progress`) collect says how far each sequence is, not only when one finishes: with
    progress_every_s=0 one line per frame pair (frames done / total, elapsed, rate), the same bytes written."""
    out, _ = tiny_run
    cfg = tiny(city_dir)
    lines: list[str] = []
    again = tmp_path / "again"
    collect(CollectInputs.from_resolved(cfg), again, progress=lines.append, progress_every_s=0.0)
    assert _progress_counts(lines) == {"train-small-t000": [(k, 6) for k in range(1, 7)],
                                       "validation-small-t005": [(k, 5) for k in range(1, 6)]}
    assert [line.split(" (")[0] for line in lines if not _progress_counts([line])] == [
        "1/2 train-small-t000: 6 frame pairs", "2/2 validation-small-t005: 5 frame pairs"]
    for seq in ("train/train-small-t000", "validation/validation-small-t005"):
        assert (out / seq / "frames.csv").read_text() == (again / seq / "frames.csv").read_text()
    # the default: at most one line every 30 s, so none in a run this short
    lines.clear()
    collect(CollectInputs.from_resolved(cfg), tmp_path / "quiet", progress=lines.append)
    assert _progress_counts(lines) == {} and len(lines) == 2


@pytest.mark.slow  # spawns two worker processes (each loads numba kernels and builds the city's textures)
def test_process_pool_gives_the_same_bytes(tiny_run, tmp_path, city_dir):
    out, _ = tiny_run
    cfg = tiny(city_dir)
    cfg["parallel"] = {"n_jobs": 2}
    again = tmp_path / "again"
    lines: list[str] = []
    collect(CollectInputs.from_resolved(cfg), again, progress=lines.append, progress_every_s=0.0)
    # the workers' progress lines come back through the queue, every one of them
    assert _progress_counts(lines) == {"train-small-t000": [(k, 6) for k in range(1, 7)],
                                       "validation-small-t005": [(k, 5) for k in range(1, 6)]}
    for seq in ("train/train-small-t000", "validation/validation-small-t005"):
        a, b = out / seq, again / seq
        assert (a / "frames.csv").read_text() == (b / "frames.csv").read_text()
        assert (a / "sequence.yaml").read_text() == (b / "sequence.yaml").read_text()
        for p in sorted((a / "cam2").iterdir()):
            assert p.read_bytes() == (b / "cam2" / p.name).read_bytes()


def test_failure_leaves_previous_output_untouched(tmp_path, city_dir):
    out = tmp_path / "raw"
    (out / "train" / "keep").mkdir(parents=True)
    (out / "train" / "keep" / "marker").write_text("x")
    cfg = tiny(city_dir)
    cfg["world"]["render"]["blur"] = "smeared"
    with pytest.raises(ConfigError, match="world.render.blur"):
        collect(CollectInputs.from_resolved(cfg), out, progress=False)
    assert (out / "train" / "keep" / "marker").read_text() == "x"
    assert sorted(p.name for p in out.iterdir()) == ["train"]


def _with(path, value, city_dir):
    cfg = tiny(city_dir)
    node = cfg
    for part in path[:-1]:
        node = node[part]
    if value is KeyError:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return cfg


@pytest.mark.parametrize(
    "path, value, key",
    [
        (("collect", "n_jobz"), 2, "collect.n_jobz"),
        (("collect", "warmup_frames"), -1, "collect.warmup_frames"),
        (("collect", "sensor_randomisation"), 0.9, "collect.sensor_randomisation"),
        (("collect", "initial_exposure_us"), 10.0, "collect.initial_exposure_us"),
        (("collect", "reference_controller"), KeyError, "collect.reference_controller"),
        (("collect", "splits", "train", "frames"), 1, "collect.splits.train.frames"),
        (("collect", "splits", "train", "n_sequence"), 1, "collect.splits.train.n_sequence"),
        (("collect", "splits", "holdout"), {}, "collect.splits.holdout"),
        (("world", "cities", "train"), "atlantis", "world.cities.train"),
        (("world", "cities", "validation"), KeyError, "world.cities.validation"),
        (("world", "render", "width"), 0, "world.render.width"),
        (("controllers", "agae", "damping"), 7.0, "controllers.agae.damping"),
        (("rig", "width"), 320, "rig.width"),
        (("rig", "fps"), "fast", "rig.fps"),
        (("rig", "perturbation"), {"max_fraction": 2.0}, "rig.perturbation.max_fraction"),
        (("seed",), -1, "seed"),
        (("sensor",), {"full_well_e": -5.0}, "sensor.full_well_e"),
    ],
)
def test_bad_config_names_the_key(path, value, key, tmp_path, city_dir):
    with pytest.raises(ConfigError) as e:
        collect(CollectInputs.from_resolved(_with(path, value, city_dir)), tmp_path / "raw", progress=False)
    assert e.value.key == key
    assert not (tmp_path / "raw").exists()


def test_plan_names_and_seeds(city_dir):
    cfg = tiny(city_dir)
    cfg["collect"]["splits"]["train"]["n_sequences"] = 3
    jobs = plan_sequences(CollectInputs.from_resolved(cfg))
    assert [j.name for j in jobs] == ["train-small-t000", "train-small-t001", "train-small-t002", "validation-small-t005"]
    assert len({j.seed for j in jobs}) == 4
    assert [j.traversal_frames for j in jobs] == [8, 8, 8, 7]  # warm-up + recorded
    assert plan_sequences(CollectInputs.from_resolved(cfg)) == jobs


def test_config_file_parses():
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    d = yaml.safe_load((root / "conf" / "collect" / "default.yaml").read_text())
    cfg = CollectConfig.from_dict(d)
    assert cfg.splits["train"].n_sequences >= 8 and cfg.splits["train"].frames >= 300
    rig = RigConfig.from_dict(yaml.safe_load((root / "conf" / "rig" / "default.yaml").read_text()))
    assert rig.baseline_m == 0.0392 and rig.fps == 15.0


def test_every_config_problem_in_one_pass(city_dir):
    cfg = _with(("collect", "warmup_frames"), -1, city_dir)
    cfg["rig"]["fps"] = "fast"
    cfg["world"]["render"]["width"] = 0
    cfg["seed"] = -1
    with pytest.raises(ConfigError) as e:
        CollectInputs.from_resolved(cfg)
    assert e.value.problems == [
        ("collect.warmup_frames", "must be an integer >= 0, got -1"),
        ("seed", "must be an integer >= 0, got -1"),
        ("world.render.width", "must be an integer in [16, 8192] pixels, got 0"),
        ("rig.fps", "must be a number > 0, got 'fast'"),
    ]


def test_inputs_are_built_once_and_picklable_for_the_workers(city_dir):
    import pickle

    inputs = CollectInputs.from_resolved(tiny(city_dir))
    assert inputs.seed == 3 and inputs.reference_section == {"damping": 0.2} and inputs.reference_config.damping == 0.2
    assert (inputs.world.render.width, inputs.world.render.height, inputs.rig.fps) == (64, 48, 15.0)
    assert pickle.loads(pickle.dumps(inputs)) == inputs
    with pytest.raises(AttributeError):  # frozen: a worker cannot change what the stage built
        inputs.seed = 4
