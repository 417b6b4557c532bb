from __future__ import annotations

import pytest

from expoctl.errors import InputError
from stages.iterations import for_iteration


def test_later_iterations_swap_paths_and_keep_the_earlier_ones():
    cfg = {"paths": {"raw_dir": "data/raw", "model": "models/controller.pt", "frames": "f.parquet"},
           "iteration2": {"enabled": True, "paths": {"raw_dir": "data/raw_iter2", "model": "models/c2.pt"}},
           "iteration3": {"enabled": False, "paths": {"raw_dir": "data/raw_iter3", "model": "models/c3.pt"}}}
    it2 = for_iteration(cfg, 2)
    assert it2["paths"] == {"raw_dir": "data/raw_iter2", "model": "models/c2.pt", "frames": "f.parquet"}
    assert it2["paths_prev"] == cfg["paths"] and it2["iteration"] == 2
    assert it2["raw_dirs_prev"] == ["data/raw"] and it2["iteration_block"] is cfg["iteration2"]
    it3 = for_iteration(cfg, 3)
    assert it3["paths"] == {"raw_dir": "data/raw_iter3", "model": "models/c3.pt", "frames": "f.parquet"}
    assert it3["paths_prev"] == it2["paths"]  # iteration 2's model is iteration 3's reference
    assert it3["raw_dirs_prev"] == ["data/raw", "data/raw_iter2"] and it3["iteration_block"]["enabled"] is False
    assert for_iteration(cfg, 1) is cfg
    with pytest.raises(InputError, match="iteration2.paths"):
        for_iteration({"paths": {}}, 2)
    with pytest.raises(InputError, match="iteration3.paths"):
        for_iteration({k: v for k, v in cfg.items() if k != "iteration3"}, 3)
    with pytest.raises(InputError, match="--iteration"):
        for_iteration(cfg, 4)
