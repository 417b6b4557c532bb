"""The `ray` backend end to end: a REAL two-node Ray cluster on 127.0.0.1 (one CPU per node, Ray's token
authentication on, started here and stopped on exit), and collect, features and evaluate at fixture scale through it,
through worker processes on this host and in this process (host thread counts, one job at a time): the same bytes
and tables, so where and on how many workers a job runs is not part of its result (which is why `parallel` is no
DVC param, stages/table.py). A client without the cluster's token is refused. CI installs the ray extra (.ci/run),
so this never skips there."""

from __future__ import annotations

import copy
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml
from eval_fixtures import make_fixture_project

from expoctl.parallel import ParallelConfig

pytest.importorskip("ray")

pytestmark = pytest.mark.slow  # a two-node cluster (7 s up, 6 s down) and three stages twice at fixture scale: 28 s

#: collect at its test's scale (tests/sim/test_collect.py): two short sequences of a cheap city, 64×48
TINY_COLLECT = {
    "seed": 3,
    "rig": {"baseline_m": 0.0392, "fps": 15.0},
    "world": {"cities": {"train": "small", "validation": "small"}, "city_dir": None,
              "render": {"width": 64, "height": 48, "hfov_deg": 70.0}},
    "collect": {"reference_controller": "agae", "initial_gain_db": 0.0, "initial_exposure_us": 5000.0,
                "warmup_frames": 2, "sensor_randomisation": 0.15,
                "splits": {"train": {"first_traversal": 0, "n_sequences": 1, "frames": 6},
                           "validation": {"first_traversal": 5, "n_sequences": 1, "frames": 5}, "test": None}},
    "controllers": {"agae": {"damping": 0.2}},
}
FEATURES = {"frontends": ["orb", "viso"], "orb": {"working_size": None, "count_nfeatures": 400,
                                                  "match_nfeatures": 200}, "seed": 3}


@pytest.fixture(scope="module")
def ray_address(tmp_path_factory):
    from ray_cluster import local_ray_cluster

    with local_ray_cluster(2, tmp_path_factory.mktemp("ray")) as address:
        yield address


def _files(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _frames_table(raw: Path) -> pd.DataFrame:
    """The features stage's input for the collected PNGs (what ingest would list, without downsampling)."""
    rows = [{"sequence": png.parent.parent.name, "frame_id": int(png.stem), "camera": int(png.parent.name[3:]),
             "image_path": png.relative_to(raw).as_posix()} for png in sorted(raw.glob("*/*/cam?/*.png"))]
    return pd.DataFrame(rows)


def test_collect_features_evaluate_on_a_two_node_ray_cluster_match_processes(ray_address, tmp_path):
    import ray

    from expoctl.evaluation.inputs import EvaluationInputs
    from expoctl.evaluation.runner import evaluate, write_outputs
    from expoctl.features.pipeline import compute_features
    from expoctl.sim.collect import CollectInputs, collect

    # A client on this host without the cluster's token must be refused: started now, it waits out Ray's ~20 s of
    # retries while the rest of the test runs.
    refused = _connect_without_token(ray_address)
    backends = {"processes": ParallelConfig("processes", n_jobs=2), "ray": ParallelConfig("ray", ray_address),
                "inprocess": ParallelConfig("inprocess")}

    # collect: two sequences; the per-frame progress lines come back from the Ray workers too
    city_dir = tmp_path / "cities"
    city_dir.mkdir()
    (city_dir / "small.yaml").write_text(yaml.safe_dump({"base": "train", "name": "small",
                                                         "textures": {"tile_px": 256}}))
    raw, lines = {}, {}
    for name, parallel in backends.items():
        cfg = copy.deepcopy(TINY_COLLECT)
        cfg["world"]["city_dir"] = str(city_dir)
        cfg["parallel"] = {"backend": parallel.backend, "address": parallel.address, "n_jobs": parallel.n_jobs}
        inputs = CollectInputs.from_resolved(cfg)
        assert inputs.parallel == parallel
        raw[name], lines[name] = tmp_path / f"raw_{name}", []
        collect(inputs, raw[name], progress=lines[name].append, progress_every_s=0.0)
    assert len(ray.nodes()) == 2 and all(n["Alive"] for n in ray.nodes())  # connected to the two-node cluster
    a, b = _files(raw["processes"]), _files(raw["ray"])
    assert len(a) > 20 and a.keys() == b.keys()
    assert [k for k in a if a[k] != b[k]] == []
    assert _files(raw["inprocess"]) == a  # one job at a time, numba's and torch's host thread counts
    # one progress line per frame pair, from the workers, as from worker processes
    progress = {name: sorted(line.split(",")[0] for line in ls if "frame pairs," in line) for name, ls in lines.items()}
    assert len(progress["ray"]) == 6 + 5 and progress["ray"] == progress["processes"]

    # features over the collected images: both front ends, one sequence per job
    frames = _frames_table(raw["processes"])
    tables = {name: compute_features(frames, raw["processes"], FEATURES, progress=False, parallel=parallel)
              for name, parallel in backends.items()}
    for name in ("ray", "inprocess"):
        for got, want in zip(tables[name], tables["processes"]):
            assert len(want) > 0
            pd.testing.assert_frame_equal(got, want)

    # evaluate: two windows × two controllers, the learned network among them (torch in the Ray workers)
    outputs = {}
    for name, parallel in backends.items():
        root = tmp_path / f"eval_{name}"
        cfg = make_fixture_project(root, controllers=["agae", "learned"])
        result = evaluate(EvaluationInputs.from_resolved(cfg), root, parallel=parallel)
        assert len(result.runs) == 4
        write_outputs(result, root / "reports")
        outputs[name] = _files(root / "reports")
    a = outputs["processes"]
    assert "eval/frames.parquet" in a and "metrics.json" in a
    for name in ("ray", "inprocess"):
        b = outputs[name]
        assert a.keys() == b.keys()
        # every byte, but for the two tables that record wall-clock timings (controller_ms per frame, seconds per
        # run): those differ between any two runs, whatever the backend; their other columns must be equal
        assert [k for k in a if a[k] != b[k] and k not in TIMED] == [], name
        for k in TIMED:
            want, got = (pd.read_parquet(tmp_path / f"eval_{n}" / "reports" / k) for n in ("processes", name))
            clock = [c for c in want.columns if c.endswith("_ms") or "seconds" in c or "_ms_" in c]
            pd.testing.assert_frame_equal(got.drop(columns=clock), want.drop(columns=clock))

    # the pinned numeric mode of the driver reaches the Ray workers, which do not inherit its environment
    # (expoctl.parallel.runtime_env); os.getenv runs in the worker
    from expoctl.numerics import PINNED_ENV
    from expoctl.parallel import collect_all, disconnect_ray

    disconnect_ray()  # the runtime env is fixed when the driver connects
    with pytest.MonkeyPatch.context() as mp:
        for k, v in PINNED_ENV.items():
            mp.setenv(k, v)
        seen = collect_all(os.getenv, ["ONEDNN_MAX_CPU_ISA", "NUMBA_CPU_NAME", "OPENCV_CPU_DISABLE", "RAY_AUTH_MODE"],
                           parallel=backends["ray"])
    disconnect_ray()
    assert seen == ["AVX2", "haswell", PINNED_ENV["OPENCV_CPU_DISABLE"], "token"]

    out, err = refused.communicate(timeout=120)
    assert refused.returncode == 3, (out, err)  # ConfigError naming parallel.address, and the token hint
    assert "parallel.address" in err and "RAY_AUTH_MODE=token" in err, err


def _connect_without_token(address: str) -> subprocess.Popen:
    """A driver on this host, as a stage would connect, with no token (auth off on its side): should be refused.
    Exits 3 on the expected ConfigError, 0 if it got in."""
    code = ("import sys\nfrom expoctl.errors import ConfigError\nfrom expoctl.parallel import connect_ray\n"
            "try:\n    connect_ray(sys.argv[1])\nexcept ConfigError as exc:\n    print(exc, file=sys.stderr)\n"
            "    sys.exit(3)\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_AUTH")}
    env["RAY_AUTH_MODE"] = "disabled"
    return subprocess.Popen([sys.executable, "-c", code, address], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


TIMED = ("eval/frames.parquet", "eval/runs.parquet")
