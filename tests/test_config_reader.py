"""The config checker library: typed reads, named bounds, every problem of a pass in one ConfigError."""

import pytest

from expoctl.config_reader import REQUIRED, Problems, Section, bounds_text, read_seed
from expoctl.errors import ConfigError, InputError


def _problems(read) -> list[tuple[str, str]]:
    with pytest.raises(ConfigError) as exc:
        read()
    return exc.value.problems


def test_bounds_text_names_inclusive_and_exclusive_ends():
    assert bounds_text(min=0, max=1) == "in [0, 1]"
    assert bounds_text(above=0, below=180) == "in (0, 180)"
    assert bounds_text(min=0, below=1) == "in [0, 1)"
    assert bounds_text(above=0, max=1) == "in (0, 1]"
    assert (bounds_text(min=1), bounds_text(above=0), bounds_text(max=2), bounds_text(below=3)) == (
        ">= 1", "> 0", "<= 2", "< 3")
    assert bounds_text() == ""


def test_values_and_defaults():
    r = Section({"n": 3, "x": 2, "flag": True, "mode": "fast", "name": "agae", "raw": [1, 2]}, "g")
    assert r.integer("n", 1, min=0) == 3
    x = r.number("x", 1.0, min=0)
    assert x == 2.0 and isinstance(x, float)
    assert r.boolean("flag", False) is True
    assert r.choice("mode", ("fast", "reference"), "reference") == "fast"
    assert r.text("name") == "agae"
    assert r.value("raw") == [1, 2]
    assert r.integer("absent", 7) == 7 and r.number("gone", None, nullable=True) is None
    r.done()


@pytest.mark.parametrize("v, ok", [(0, False), (0.0, False), (1e-9, True), (180, False), (179.999, True)])
def test_exclusive_bounds_at_the_edge(v, ok):
    r = Section({"hfov_deg": v}, "world.render")
    got = r.number("hfov_deg", 59.1, above=0, below=180, unit="degrees")
    if ok:
        assert got == v
        r.done()
    else:
        assert got == 59.1
        assert _problems(r.done) == [("world.render.hfov_deg", f"must be a number in (0, 180) degrees, got {v!r}")]


@pytest.mark.parametrize("v, ok", [(0.0, True), (0.05, True), (-1e-9, False), (0.0500001, False)])
def test_inclusive_bounds_at_the_edge(v, ok):
    r = Section({"glare_fraction": v}, "world.render")
    got = r.number("glare_fraction", 0.005, min=0.0, max=0.05)
    if ok:
        assert got == v
        r.done()
    else:
        assert got == 0.005  # the read goes on with the default
        assert _problems(r.done) == [("world.render.glare_fraction", f"must be a number in [0.0, 0.05], got {v!r}")]


def test_integer_edges_and_types():
    r = Section({"a": 1, "b": 0, "c": True, "d": 2.0, "e": None}, "g")
    r.integer("a", min=1)
    r.integer("b", min=1)
    r.integer("c", min=0)  # YAML true is not a number
    r.integer("d", above=0)
    r.integer("e", min=0, nullable=True)
    assert _problems(r.done) == [
        ("g.b", "must be an integer >= 1, got 0"),
        ("g.c", "must be an integer >= 0, got True"),
        ("g.d", "must be an integer > 0, got 2.0"),
    ]


def test_every_problem_in_one_pass_with_full_key_paths():
    cfg = {"width": 8, "blur": "smudge", "share_render": "yes", "colour": True, "vo": {"n": -1, "extra": 1}}
    r = Section(cfg, "world.render")
    r.integer("width", 640, min=16, max=8192, unit="pixels")
    r.choice("blur", ("fast", "reference"), "fast")
    r.boolean("share_render", False)
    r.number("tmax_m", REQUIRED, above=10)
    vo = r.section("vo")
    vo.integer("n", 1, min=0)
    vo.done()
    with pytest.raises(ConfigError) as exc:
        r.done()
    err = exc.value
    assert err.problems == [
        ("world.render.width", "must be an integer in [16, 8192] pixels, got 8"),
        ("world.render.blur", "must be one of fast, reference, got 'smudge'"),
        ("world.render.share_render", "must be true or false, got 'yes'"),
        ("world.render.tmax_m", "missing"),
        ("world.render.vo.n", "must be an integer >= 0, got -1"),
        ("world.render.vo.extra", "unknown key (expected one of ['n'])"),
        ("world.render.colour", "unknown key (expected one of ['blur', 'share_render', 'tmax_m', 'vo', 'width'])"),
    ]
    assert isinstance(err, InputError) and err.key == "world.render.width"
    assert str(err) == "; ".join(f"config key '{k}': {p}" for k, p in err.problems)


def test_one_problem_keeps_the_config_error_message():
    r = Section({"fps": -1}, "rig")
    r.number("fps", 15.0, above=0)
    with pytest.raises(ConfigError) as exc:
        r.done()
    assert str(exc.value) == "config key 'rig.fps': must be a number > 0, got -1"


def test_not_a_mapping_and_required_sections():
    r = Section([1, 2], "evaluate")
    assert r.integer("n_jobs", 1, min=1) == 1
    assert _problems(r.done) == [("evaluate", "missing or not a mapping (got [1, 2])")]
    assert _problems(lambda: Section(None, "collect", required=True).done()) == [
        ("collect", "missing or not a mapping (got None)")]
    Section(None, "report").done()  # optional: absent reads as empty


def test_groups_share_one_problem_list():
    problems = Problems()
    a = Section({"fps": 0}, "rig", problems)
    a.number("fps", 15.0, above=0)
    a.done()  # not the owner: collects, does not raise
    b = Section({"hfov_deg": 200}, "world.render", problems)
    b.number("hfov_deg", 59.1, above=0, below=180)
    b.done(known=["hfov_deg"])
    assert len(problems) == 2
    assert _problems(problems.raise_if_any) == [("rig.fps", "must be a number > 0, got 0"),
                                                ("world.render.hfov_deg", "must be a number in (0, 180), got 200")]


@pytest.mark.parametrize("v, ok", [([0, 30], True), ((1.0, 1.0), True), ([6, 1], False), ([0, 31], False),
                                   ([-1, 2], False), (3, False), ([1, 2, 3], False), ([True, 2], False)])
def test_pair_is_ordered_and_bounded(v, ok):
    r = Section({"zero_gain_add_db": v}, "rig.perturbation")
    got = r.pair("zero_gain_add_db", (1.0, 6.0), min=0.0, max=30.0, unit="dB")
    if ok:
        assert got == (float(v[0]), float(v[1])) and all(isinstance(x, float) for x in got)
        r.done()
    else:
        assert got == (1.0, 6.0)
        assert _problems(r.done) == [("rig.perturbation.zero_gain_add_db",
                                      f"must be [low, high] with low <= high, each a number in [0.0, 30.0] dB, got {v!r}")]


def test_names_reports_each_unknown_and_repeated_name():
    r = Section({"controllers": ["agae", "nope", "agae"]}, "evaluate")
    assert r.names("controllers", ("agae", "shin"), ("agae",), what="controller") == ("agae",)
    assert _problems(r.done) == [
        ("evaluate.controllers", "lists a controller twice: ['agae', 'nope', 'agae']"),
        ("evaluate.controllers", "unknown controller 'nope' (known: agae, shin)"),
    ]
    r = Section({"frontends": "orb"}, "features")
    r.names("frontends", ("orb", "viso"), what="front end")
    assert _problems(r.done) == [("features.frontends", "must be a non-empty list of front ends (orb, viso), got 'orb'")]


def test_collect_adds_a_config_errors_problems():
    problems = Problems()

    def legacy(v):
        if v < 0:
            raise ConfigError("sensor.full_well_e", f"must be > 0, got {v}")
        return v

    assert problems.collect(legacy, 3) == 3 and len(problems) == 0
    assert problems.collect(legacy, -5) is None
    problems.add("rig.fps", "must be a number > 0, got 0")
    assert _problems(problems.raise_if_any) == [("sensor.full_well_e", "must be > 0, got -5"),
                                                ("rig.fps", "must be a number > 0, got 0")]


@pytest.mark.parametrize("cfg, seed, problem", [({}, 0, None), ({"seed": 7}, 7, None),
                                                ({"seed": -1}, 0, "must be an integer >= 0, got -1"),
                                                ({"seed": True}, 0, "must be an integer >= 0, got True")])
def test_seed_is_one_top_level_key(cfg, seed, problem):
    top = Section(cfg, "")
    assert read_seed(top) == seed
    if problem is None:
        top.problems.raise_if_any()
    else:
        assert _problems(top.problems.raise_if_any) == [("seed", problem)]
