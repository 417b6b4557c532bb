"""dvc.yaml declares, per stage, exactly the resolved-config keys the stage reads (stages.keys, from the stage table
stages/table.py), and DVC sees a change of any of them.

The stages are read as DVC resolves them (its `foreach` expands the later iterations), not as raw YAML."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from stages.keys import LAST_ITERATION, STAGE_KEYS, split_stage_name, stage_keys, stage_name

PROJECT_ROOT = Path(__file__).resolve().parents[2]
ITERATION_STAGES = ("collect", "ingest", "features", "labels", "samples", "train")


@pytest.fixture(scope="module")
def stages() -> dict:
    """{stage name: (cmd, config keys declared as params, deps, outs, metrics)} as DVC resolves dvc.yaml."""
    from dvc.repo import Repo

    out = {}
    for s in Repo(str(PROJECT_ROOT)).index.stages:
        params = [d for d in s.deps if type(d).__name__ == "ParamsDependency"]
        keys = [k for d in params if Path(d.def_path).name == "resolved.yaml" for k in d.params]
        other = {Path(d.def_path).name: list(d.params) for d in params if Path(d.def_path).name != "resolved.yaml"}
        deps = [str(d) for d in s.deps if type(d).__name__ != "ParamsDependency"]
        out[s.name] = (s.cmd, keys, other, deps, [str(o) for o in s.outs if not o.metric],
                       [str(o) for o in s.outs if o.metric])
    return out


def test_every_stage_declares_its_config_keys(stages):
    # compose tracks the whole params.yaml (an empty key list), so a key other than `overrides` reaches it and is refused
    assert stages["compose"][2] == {"params.yaml": []} and stages["compose"][1] == []
    for name, (cmd, keys, _, _, _, _) in stages.items():
        if name in ("compose", "guard"):
            continue
        base, n = split_stage_name(name)
        assert base in STAGE_KEYS, f"stage {name} has no STAGE_KEYS entry"
        # an iteration-2 stage repeats its own block's entry where later iterations name an earlier one
        assert sorted(set(keys)) == sorted(set(stage_keys(name))), name
        expected_cmd = f"python -m stages.{base}" + (f" --iteration {n}" if n > 1 else "")
        assert cmd == expected_cmd, name


def test_every_iteration_has_its_stages_with_its_own_outputs(stages):
    for n in range(2, LAST_ITERATION + 1):
        for base in ITERATION_STAGES:
            assert stage_name(base, n) in stages, f"{stage_name(base, n)} missing from dvc.yaml"
        collect = stages[stage_name("collect", n)]
        previous_model = "models/controller.pt" if n == 2 else f"models/controller_iter{n - 1}.pt"
        # the previous network, and the probe that gates it (a file, or the directory holding it)
        assert previous_model in collect[3] and _covered("src/expoctl/selection/saturation_probe.py", collect[3])
        # its raw data, and which controller drove camera 1 (the reference gate's decision)
        assert collect[4] == [f"data/raw_iter{n}", f"reports/iter{n}/collect_reference.json"]
        ingest = stages[stage_name("ingest", n)]
        assert set(ingest[3]) >= {"data/raw"} | {f"data/raw_iter{k}" for k in range(2, n + 1)}
        train = stages[stage_name("train", n)]
        assert train[4] == [f"models/controller_iter{n}.pt", f"models/controller_iter{n}.onnx",
                            f"reports/iter{n}/train.json"]
    assert not any(name.startswith(tuple(f"{b}_iter@{LAST_ITERATION + 1}" for b in ITERATION_STAGES))
                   for name in stages)


def _covered(path: str, deps: list[str]) -> bool:
    return any(path == d or path.startswith(d.rstrip("/") + "/") for d in deps)


def test_one_small_headline_metric(stages):
    """`dvc metrics show` prints only reports/headline.json; the full tables are outputs."""
    declared = {name: m for name, (*_, m) in stages.items() if m}
    assert declared == {"report": ["reports/headline.json"]}
    assert "reports/metrics.json" in stages["evaluate"][4] and "reports/train.json" in stages["train"][4]


def test_stage_keys_exist_in_every_scale(stages):
    from stages.compose import compose_config
    from stages.keys import select_keys
    from stages.table import derived_config

    for scale in ("fixture", "default", "paper"):
        cfg = compose_config([f"scale={scale}"])
        cfg.update(derived_config(cfg))  # as compose writes it
        assert cfg["scale_name"] == scale
        for name in stages:
            if name not in ("compose", "guard"):
                select_keys(cfg, stage_keys(name))  # raises if a key is missing


def test_raw_dvc_yaml_has_no_copied_iteration_blocks():
    doc = yaml.safe_load((PROJECT_ROOT / "dvc.yaml").read_text())
    raw = doc["stages"]
    assert not [name for name in raw if name[-1].isdigit()], "write later iterations through foreach"
    for base in ITERATION_STAGES:
        assert raw[f"{base}_iter"]["foreach"] == "${later_iterations}", base
    (iterations,) = [v["later_iterations"] for v in doc["vars"] if "later_iterations" in v]
    assert sorted(iterations, key=int) == [str(n) for n in range(2, LAST_ITERATION + 1)]


def test_dvc_status_sees_a_change_of_the_controller_collect_builds(project_copy):
    """With `collect.reference_controller: shin`, a change of `controllers.shin` makes `dvc status` list collect as
    changed (its params: compose copies the section it reads to `collect_controllers.iteration1`); a change of a
    controller collect does not build leaves it up to date."""
    p = project_copy
    shin = ["scale=fixture", "collect.reference_controller=shin"]
    p.set_overrides(shin)
    p.dvc("repro", "compose")
    (p.root / "data" / "raw").mkdir(parents=True)
    (p.root / "data" / "raw" / "stand-in.txt").write_text("what collect wrote\n")
    p.dvc("commit", "-f", "collect")  # dvc.lock records collect as run with this config
    assert "collect" not in p.dvc("status", "collect").stdout

    p.set_overrides(shin + ["controllers.shim.k_p=0.3"])  # a controller collect does not build
    p.dvc("repro", "compose")
    assert "collect" not in p.dvc("status", "collect").stdout

    p.set_overrides(shin + ["controllers.shin.alpha=0.5"])
    p.dvc("repro", "compose")
    status = p.dvc("status", "collect").stdout
    assert "collect:" in status and "collect_controllers.iteration1" in status, status
