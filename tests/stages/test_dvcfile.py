"""stages.dvcfile reads dvc.yaml as DVC itself resolves it (foreach expanded) and dvc.lock as DVC writes it."""

from __future__ import annotations

from pathlib import Path

import yaml

from stages.dvcfile import declared_outputs, dir_manifest, locked_outputs, resolved_stages

PROJECT_ROOT = Path(__file__).resolve().parents[2]


def test_stages_and_outputs_match_dvcs_own_resolution():
    from dvc.repo import Repo

    dvc_outs = {(s.name, str(o.def_path), bool(o.use_cache), bool(o.persist))
                for s in Repo(str(PROJECT_ROOT)).index.stages for o in s.outs}
    ours = {(o.stage, o.path, o.cache, o.persist) for o in declared_outputs(PROJECT_ROOT)}
    assert ours == dvc_outs
    assert set(resolved_stages(PROJECT_ROOT)) == {s.name for s in Repo(str(PROJECT_ROOT)).index.stages}


def test_every_output_persists():
    """A failed or interrupted stage must leave the last good outputs: DVC deletes non-persistent ones first."""
    assert [o.path for o in declared_outputs(PROJECT_ROOT) if not o.persist] == []


def test_lock_and_manifest(tmp_path):
    (tmp_path / "dvc.lock").write_text(yaml.safe_dump({"schema": "2.0", "stages": {"collect": {"outs": [
        {"path": "data/raw", "hash": "md5", "md5": "ab12.dir", "size": 10, "nfiles": 2}]}}}))
    (locked,) = locked_outputs(tmp_path).values()
    assert (locked.stage, locked.path, locked.is_dir, locked.nfiles) == ("collect", "data/raw", True, 2)
    assert dir_manifest(tmp_path, "ab12.dir") is None  # not in the cache
    manifest = tmp_path / ".dvc" / "cache" / "files" / "md5" / "ab" / "12.dir"
    manifest.parent.mkdir(parents=True)
    manifest.write_text('[{"md5": "x", "relpath": "train/s/frames.csv"}, {"md5": "y", "relpath": "a.txt"}]')
    assert dir_manifest(tmp_path, "ab12.dir") == {"train/s/frames.csv", "a.txt"}
    assert locked_outputs(tmp_path / "nowhere") == {}
