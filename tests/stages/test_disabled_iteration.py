"""A stage of a disabled later iteration copies the previous iteration's outputs instead of recomputing them."""

from __future__ import annotations

import pytest

import stages.common as common
from expoctl.errors import InputError
from stages.compose import compose_config
from stages.iterations import for_iteration


@pytest.fixture
def root(tmp_path, monkeypatch):
    monkeypatch.setattr(common, "PROJECT_ROOT", tmp_path)
    return tmp_path


def _cfg(enabled: bool):
    return for_iteration(compose_config(["scale=fixture", f"iteration3.enabled={str(enabled).lower()}"]), 3)


def test_disabled_copies_every_output_byte_for_byte(root):
    (root / "data" / "iter2" / "images" / "seq").mkdir(parents=True)
    (root / "data" / "iter2" / "images" / "seq" / "0.png").write_bytes(b"png")
    (root / "data" / "iter2" / "frames.parquet").write_bytes(b"frames")
    (root / "data" / "iter2" / "labels.parquet").write_bytes(b"labels")
    (root / "reports" / "iter2").mkdir(parents=True)
    (root / "reports" / "iter2" / "labels.md").write_text("md")
    (root / "reports" / "iter2" / "labels.json").write_text("{}")
    assert common.copied_when_disabled("ingest", _cfg(False))
    assert (root / "data" / "iter3" / "frames.parquet").read_bytes() == b"frames"
    assert (root / "data" / "iter3" / "images" / "seq" / "0.png").read_bytes() == b"png"
    assert common.copied_when_disabled("labels", _cfg(False))
    assert (root / "data" / "iter3" / "labels.parquet").read_bytes() == b"labels"
    assert (root / "reports" / "iter3" / "labels.md").read_text() == "md"


def test_enabled_first_iteration_and_other_stages_run_as_usual(root):
    assert not common.copied_when_disabled("ingest", _cfg(True))
    assert not common.copied_when_disabled("train", _cfg(False))  # train keeps its own (logged) copy
    assert not common.copied_when_disabled("ingest", compose_config(["scale=fixture"]))


def test_missing_previous_outputs_are_named(root):
    with pytest.raises(InputError, match=r"iteration 3 is disabled.*data/iter2/features.parquet, "
                                         r"data/iter2/matches.parquet are missing"):
        common.copied_when_disabled("features", _cfg(False))
