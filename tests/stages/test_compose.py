from __future__ import annotations

import pytest

from expoctl.errors import InputError
from stages.compose import compose_config


def test_overrides_apply_and_resolve():
    cfg = compose_config(["scale=fixture", "ingest.image_width=32", "seed=7"])
    assert cfg["ingest"]["image_width"] == 32 and cfg["seed"] == 7 and cfg["scale_name"] == "fixture"
    assert cfg["paths"]["frames"] == "data/frames.parquet"


@pytest.mark.parametrize("overrides,words", [
    (["scale=huge"], "scale"),
    (["ingest.no_such_key=1"], "no_such_key"),
    ("scale=fixture", "must be a list of strings"),
])
def test_bad_overrides_name_the_problem(overrides, words):
    with pytest.raises(InputError, match=words):
        compose_config(overrides)
