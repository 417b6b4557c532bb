"""dvc.yaml declares, per stage, exactly the resolved-config keys the stage reads (stages.common.STAGE_KEYS)."""

from __future__ import annotations

from pathlib import Path

import yaml

from stages.common import STAGE_KEYS, split_stage_name, stage_keys

PROJECT_ROOT = Path(__file__).resolve().parents[2]


def _declared_keys(stage: dict) -> list[str]:
    keys = []
    for entry in stage.get("params", []):
        if isinstance(entry, dict) and "configs/resolved.yaml" in entry:
            keys.extend(entry["configs/resolved.yaml"])
    return keys


def test_every_stage_declares_its_config_keys():
    stages = yaml.safe_load((PROJECT_ROOT / "dvc.yaml").read_text())["stages"]
    for name, stage in stages.items():
        if name == "compose":
            assert stage["params"] == ["overrides"]
            continue
        base, n = split_stage_name(name)
        assert base in STAGE_KEYS, f"stage {name} has no STAGE_KEYS entry"
        assert sorted(_declared_keys(stage)) == sorted(stage_keys(name)), name
        expected_cmd = f"python -m stages.{base}" + (f" --iteration {n}" if n > 1 else "")
        assert stage["cmd"] == expected_cmd, name


def test_stage_keys_exist_in_every_scale():
    from stages.compose import compose_config
    from stages.common import select_keys

    for scale in ("fixture", "default", "paper"):
        cfg = compose_config([f"scale={scale}"])
        assert cfg["scale_name"] == scale
        stages = yaml.safe_load((PROJECT_ROOT / "dvc.yaml").read_text())["stages"]
        for name in stages:
            if name != "compose":
                select_keys(cfg, stage_keys(name))  # raises if a key is missing
