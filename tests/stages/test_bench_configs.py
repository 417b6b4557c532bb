"""The benchmark configs packaged with expoctl (stages/bench_configs.py) are conf/ composed at their scale: a change to
conf/ that was not followed by `python -m stages.bench_configs --write` fails here, naming the file and the fix."""

from __future__ import annotations

import yaml

from stages import bench_configs


def test_packaged_configs_are_what_conf_gives():
    problems = bench_configs.drift()
    assert not problems, "\n".join(problems)


def test_drift_names_the_file_and_the_fix(tmp_path, monkeypatch):
    for scale in bench_configs.scales():
        (tmp_path / f"{scale}.yaml").write_text((bench_configs.CONFIG_DIR / f"{scale}.yaml").read_text())
    edited = tmp_path / "fixture.yaml"
    edited.write_text(edited.read_text().replace("seed: 0\n", "seed: 1\n"))
    (tmp_path / "default.yaml").unlink()
    monkeypatch.setattr(bench_configs, "CONFIG_DIR", tmp_path)
    monkeypatch.setattr(bench_configs, "PROJECT_ROOT", tmp_path.parent)
    assert bench_configs.drift() == [f"{tmp_path.name}/default.yaml is missing",
                                     f"{tmp_path.name}/fixture.yaml is not what conf/ gives at scale=fixture",
                                     f"run `{bench_configs.WRITE_COMMAND}`"]


def test_packaged_configs_need_no_checkout():
    """No conf/ beside a wheel: cities by packaged name, no record of the generating machine's plugins."""
    for scale in bench_configs.scales():
        cfg = yaml.safe_load((bench_configs.CONFIG_DIR / f"{scale}.yaml").read_text())
        assert cfg["world"]["city_dir"] is None
        assert not set(bench_configs.DERIVED_KEYS) & set(cfg)
