from __future__ import annotations

from pathlib import Path

import pytest

from expoctl.errors import InputError
from stages.project import load_resolved, main_project_root


def test_main_project_root_escapes_dvc_queue_copies():
    assert main_project_root(Path("/home/u/proj/.dvc/tmp/exps/tmpab12/")) == Path("/home/u/proj")
    assert main_project_root(Path("/home/u/proj")) == Path("/home/u/proj")


def test_load_resolved_names_the_file(tmp_path):
    with pytest.raises(InputError, match=r"resolved.yaml: missing; run the compose stage first"):
        load_resolved(tmp_path / "resolved.yaml")
    (tmp_path / "list.yaml").write_text("- a\n- b\n")
    with pytest.raises(InputError, match=r"list.yaml: not a YAML mapping"):
        load_resolved(tmp_path / "list.yaml")
    (tmp_path / "ok.yaml").write_text("seed: 3\n")
    assert load_resolved(tmp_path / "ok.yaml") == {"seed": 3}
