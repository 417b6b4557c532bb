"""The numeric mode (expoctl.numerics, stages/numerics.py): what it sets, over what, when, and what it records. The
real stage processes are checked by the end-to-end test (tests/pipeline/test_dvc_pipeline.py: reports/numerics.json
says pinned, applied before any import, and the fixture's bytes match the manifest)."""

from __future__ import annotations

import os

import pytest
import yaml

from expoctl.errors import ConfigError
from expoctl.numerics import (PINNED_ENV, NumericsConfig, apply_environment, baseline_warning, environment,
                              forwarded_env, meets_baseline, record, tags)

PINNED, HOST = NumericsConfig("pinned"), NumericsConfig("host")
V3 = {"avx", "avx2", "fma", "bmi1", "bmi2", "f16c", "movbe", "abm"}


@pytest.fixture
def clean_env(monkeypatch):
    """The pinned variables unset for the test, and whatever it sets undone afterwards."""
    for k in PINNED_ENV:
        monkeypatch.setenv(k, "sentinel")
        monkeypatch.delenv(k)
    return monkeypatch


def test_the_mode_is_one_checked_key():
    assert NumericsConfig.from_resolved({}) == PINNED  # the default (docs/reproducibility.md: the rule)
    assert NumericsConfig.from_dict({"mode": "host"}) == HOST
    with pytest.raises(ConfigError, match=r"numerics.mode.*one of pinned, host, got 'fast'"):
        NumericsConfig.from_dict({"mode": "fast"})
    with pytest.raises(ConfigError, match=r"numerics.threads.*unknown key"):
        NumericsConfig.from_dict({"mode": "pinned", "threads": 2})


def test_pinned_sets_the_baseline_and_host_touches_nothing():
    assert environment(HOST) == {}
    env = environment(PINNED, V3)
    assert env["ONEDNN_MAX_CPU_ISA"] == "AVX2" and env["ATEN_CPU_CAPABILITY"] == "avx2"
    assert env["NUMBA_CPU_NAME"] == "haswell" and env["NUMBA_CPU_FEATURES"] == ""  # not the host's features
    assert env["MKL_CBWR"] == "AVX2" and env["OMP_NUM_THREADS"] == "1"
    # OpenCV complains on every import about disabling a feature the CPU lacks: set only where there is one
    assert "OPENCV_CPU_DISABLE" not in env
    assert environment(PINNED, V3 | {"avx512f"})["OPENCV_CPU_DISABLE"] == "AVX512F"


def test_numpy_accepts_the_names_it_is_given():
    """numpy ignores (with a hidden ImportWarning) a NPY_DISABLE_CPU_FEATURES name outside its dispatch list, so a
    wrong name would pin nothing: every name must be one numpy dispatches."""
    from numpy._core._multiarray_umath import __cpu_dispatch__

    assert set(PINNED_ENV["NPY_DISABLE_CPU_FEATURES"].split()) <= set(__cpu_dispatch__)
    assert "X86_V3" not in PINNED_ENV["NPY_DISABLE_CPU_FEATURES"]  # the baseline itself stays


def test_apply_overrides_the_shell_and_forwards_to_workers(clean_env):
    import numpy  # noqa: F401 — loaded before the mode is applied, as in any test process
    clean_env.setenv("ONEDNN_MAX_CPU_ISA", "SSE41")  # a user's own setting must not change a pinned run's bytes
    assert forwarded_env() == {}
    late = apply_environment(PINNED)
    assert os.environ["ONEDNN_MAX_CPU_ISA"] == "AVX2"
    assert "numpy" in late  # this test process imported numpy before: too late for it, and said so
    assert forwarded_env() == PINNED_ENV  # what a Ray task gets (with OpenCV's, for a node that may have AVX-512)
    assert apply_environment(HOST) == []


def test_record_and_tags_name_mode_cpu_and_versions():
    rec = record(PINNED, ["torch"])
    assert rec["mode"] == "pinned" and rec["baseline"] == "x86-64-v3" and rec["applied_before_import"] is False
    assert rec["imported_too_early"] == ["torch"] and "numpy" in rec["versions"] and "model" in rec["cpu"]
    t = tags(rec)
    assert t["numerics.mode"] == "pinned" and t["numerics.applied_before_import"] == "False"
    assert record(HOST)["baseline"] is None


def test_a_host_below_the_baseline_is_warned():
    assert meets_baseline(V3) == (os.uname().machine == "x86_64")
    assert baseline_warning(HOST, set()) is None
    if os.uname().machine == "x86_64":
        assert "lacks avx2" in baseline_warning(PINNED, V3 - {"avx2"})
        assert baseline_warning(PINNED, V3) is None


def test_boot_only_for_a_stage_entry_point(tmp_path, clean_env):
    from stages import numerics as boot_module

    resolved = tmp_path / "resolved.yaml"
    resolved.write_text(yaml.safe_dump({"numerics": {"mode": "pinned"}}))
    assert boot_module.stage_module(["python", "-u", "-m", "stages.train", "--iteration", "2"]) == "train"
    assert boot_module.stage_module(["python", "-m", "pytest", "tests"]) is None
    assert boot_module.stage_module(["python", "-c", "import stages"]) is None
    saved = dict(boot_module._booted)
    try:
        assert not boot_module.boot(["python", "-m", "pytest"], resolved)  # a test run: nothing set
        assert "ONEDNN_MAX_CPU_ISA" not in os.environ
        assert not boot_module.boot(["python", "-m", "stages.compose"], resolved)  # before any resolved config
        assert not boot_module.boot(["python", "-m", "stages.dvc_yaml"], resolved)  # no stage
        assert boot_module.boot(["python", "-m", "stages.train"], resolved)
        assert os.environ["ONEDNN_MAX_CPU_ISA"] == "AVX2"
        assert boot_module.numerics_for({"numerics": {"mode": "pinned"}})["mode"] == "pinned"
        # the file changed between the boot and the stage's own read: refused, the environment would not match
        with pytest.raises(Exception, match="numerics.mode pinned -> host"):
            boot_module.numerics_for({"numerics": {"mode": "host"}})
        resolved.write_text(yaml.safe_dump({"numerics": {"mode": "turbo"}}))
        assert not boot_module.boot(["python", "-m", "stages.train"], resolved)
        with pytest.raises(ConfigError, match="numerics.mode"):  # stage_main prints it as one line
            boot_module.numerics_for({"numerics": {"mode": "turbo"}})
    finally:
        boot_module._booted.clear()
        boot_module._booted.update(saved)
