"""The report stage checks the final network before reading anything else: a bad checkpoint is one InputError
naming the file, and no report is written."""

from __future__ import annotations

import pytest
from eval_fixtures import make_fixture_project

from expoctl.errors import InputError
from fake_tracker import FakeTracker


def _no_work(*args, **kwargs):
    raise AssertionError("report work started before the network was checked")


@pytest.mark.parametrize("damage", ["truncated", "random", "missing"])
def test_a_bad_final_model_stops_the_report_first(tmp_path, monkeypatch, damage):
    from stages import report as stage

    monkeypatch.setattr(stage, "load_eval", _no_work)
    monkeypatch.setattr(stage, "build_report", _no_work)
    cfg = make_fixture_project(tmp_path)
    cfg["paths"]["final_model"] = "models/controller_final.pt"
    final = tmp_path / "models/controller_final.pt"
    data = (tmp_path / "models/controller.pt").read_bytes()
    if damage == "truncated":
        final.write_bytes(data[:1000])
        expected = f"{final}: truncated or not a PyTorch file (1000 bytes; the zip archive torch.save writes has no end"
    elif damage == "random":
        final.write_bytes(b"\x00" * 100)
        expected = f"{final}: truncated or not a PyTorch file (100 bytes, not starting with the zip header"
    else:
        expected = f"{final}: model checkpoint not found"
    with pytest.raises(InputError) as e:
        stage.run(cfg, FakeTracker(), project_root=tmp_path)
    assert str(e.value).startswith(expected)
    assert not (tmp_path / "reports/headline.json").exists()
