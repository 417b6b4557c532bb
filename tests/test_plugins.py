"""Plugin registries (expoctl.plugins): entry points of installed packages, and what a broken one reports.

Each test puts a throwaway distribution on sys.path the way pip leaves one (a package plus its .dist-info with
entry_points.txt), so importlib.metadata finds its entry points exactly as it finds an installed package's.
"""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path

import pytest

from expoctl.controllers.registry import CONTROLLERS, make_controller
from expoctl.errors import ConfigError
from expoctl.features.registry import FRONTENDS


def _distribution(root: Path, dist: str, package: str, modules: dict[str, str], entry_points: dict[str, dict]) -> None:
    """`root/<package>/<module>.py` for each module and `root/<dist>-0.1.dist-info` declaring the entry points."""
    (root / package).mkdir(parents=True)
    (root / package / "__init__.py").write_text("")
    for name, source in modules.items():
        (root / package / f"{name}.py").write_text(textwrap.dedent(source))
    info = root / f"{dist.replace('-', '_')}-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 0.1\n")
    lines = []
    for group, eps in entry_points.items():
        lines.append(f"[{group}]")
        lines += [f"{name} = {target}" for name, target in eps.items()]
    (info / "entry_points.txt").write_text("\n".join(lines) + "\n")


HOLD = """
    from dataclasses import dataclass

    from expoctl.controllers import Controller, Settings, register_controller


    @dataclass(frozen=True)
    class HoldConfig:
        gain_db: float = 6.0


    @register_controller("hold_ep", config=HoldConfig, label="Hold (plugin)")
    class Hold(Controller):
        def __init__(self, config):
            self.config = config

        def reset(self, initial):
            pass

        def update(self, image, applied):
            return Settings(self.config.gain_db, applied.exposure_us)
"""


@pytest.fixture
def site(tmp_path, monkeypatch):
    """A directory on sys.path for throwaway distributions; the registries forget them afterwards."""
    root = tmp_path / "site"
    root.mkdir()
    monkeypatch.syspath_prepend(str(root))
    yield root
    monkeypatch.undo()
    for name in [m for m in sys.modules if m.startswith("demo_")]:
        del sys.modules[name]
    CONTROLLERS.reload()
    FRONTENDS.reload()


def test_an_entry_point_registers_a_controller_with_its_package(site):
    _distribution(site, "demo-hold", "demo_hold", {"controller": HOLD},
                  {"expoctl.controllers": {"hold_ep": "demo_hold.controller"}})
    CONTROLLERS.reload()
    entry = CONTROLLERS.get("hold_ep")
    assert (entry.package, entry.module, entry.label) == ("demo-hold", "demo_hold.controller", "Hold (plugin)")
    assert CONTROLLERS.names()[-1] == "hold_ep"  # after every built-in (default rank)
    assert make_controller("hold_ep", {"gain_db": 3}).update(None, _settings(0.0, 200.0)) == _settings(3.0, 200.0)
    with pytest.raises(ConfigError) as exc:
        make_controller("hold_ep", {"gain_db": "bright"})
    assert exc.value.problems == [("controllers.hold_ep.gain_db", "must be a finite number, got 'bright'")]


def _settings(g, e):
    from expoctl.controllers import Settings

    return Settings(g, e)


@pytest.mark.parametrize("modules, target, expected", [
    ({"controller": "import numpy.no_such_module\n"}, "demo_bad.controller",
     "importing demo_bad.controller failed: ModuleNotFoundError: No module named 'numpy.no_such_module'"),
    ({"controller": "X = 1\n"}, "demo_bad.controller",
     "the entry point loads demo_bad.controller (module), which registers no controller named 'bad_ep'"),
    ({"controller": HOLD.replace('"hold_ep"', '"bad_ep"').replace("        def update(self, image, applied):\n"
                                                                  "            return Settings(self.config.gain_db, "
                                                                  "applied.exposure_us)\n", "")},
     "demo_bad.controller", "class Hold lacks the method(s) update every controller has"),
    ({"controller": HOLD.replace('"hold_ep"', '"bad_ep"').replace("@dataclass(frozen=True)", "@dataclass")},
     "demo_bad.controller", "config HoldConfig must be a frozen dataclass"),
])
def test_a_broken_plugin_is_named_with_its_package_and_does_not_stop_the_others(site, modules, target, expected):
    _distribution(site, "demo-bad", "demo_bad", modules, {"expoctl.controllers": {"bad_ep": target}})
    CONTROLLERS.reload()
    package, problem = CONTROLLERS.broken()["bad_ep"]
    assert package == "demo-bad" and expected in problem, problem
    assert "agae" in CONTROLLERS.names() and "bad_ep" not in CONTROLLERS.names()
    with pytest.raises(ConfigError) as exc:
        make_controller("bad_ep")
    assert exc.value.key == "controllers.bad_ep"
    assert "controller plugin 'bad_ep' (package demo-bad) is broken: " in str(exc.value)


def test_compose_check_reports_a_broken_plugin_and_an_uninstalled_one(site):
    """stages.config_check: a broken plugin stops compose, named; a name no installed package registers is
    unknown, with where plugins come from."""
    from stages.compose import compose_config
    from stages.config_check import check_resolved

    _distribution(site, "demo-bad", "demo_bad", {"controller": "raise RuntimeError('no licence key')\n"},
                  {"expoctl.controllers": {"bad_ep": "demo_bad.controller"}})
    CONTROLLERS.reload()
    cfg = compose_config(["evaluate.controllers=[agae,hold_ep]", "labels.frontend=orb+harris_ep"])
    with pytest.raises(ConfigError) as exc:
        check_resolved(cfg)
    problems = dict(exc.value.problems)
    assert problems["controllers.bad_ep"].startswith("controller plugin 'bad_ep' (package demo-bad) is broken: "
                                                     "importing demo_bad.controller failed: RuntimeError: "
                                                     "no licence key")
    assert problems["evaluate.controllers"].startswith("unknown controller 'hold_ep' (known: agae, shin, shim, "
                                                       "mean_intensity, fixed, learned, rl, oracle)")
    assert "labels.frontend" in problems and "'orb+harris_ep'" in problems["labels.frontend"]


def test_a_plugin_cannot_take_a_built_in_name(site):
    _distribution(site, "demo-clash", "demo_clash", {"controller": HOLD.replace('"hold_ep"', '"agae"')},
                  {"expoctl.controllers": {"agae": "demo_clash.controller"}})
    CONTROLLERS.reload()
    assert CONTROLLERS.get("agae").package == "expoctl"
    assert CONTROLLERS.broken()["agae"] == ("demo-clash", "its name is taken by the built-in controller")


def test_the_pipeline_records_the_registries_entry_point_groups(site):
    """stages/table.py lists installed plugins by the registries' own groups (it imports only the standard library,
    so it names them itself): an installed plugin appears in what compose records and guard writes."""
    from stages.table import PLUGIN_GROUPS, recorded_plugins

    assert PLUGIN_GROUPS == {"controllers": CONTROLLERS.group, "frontends": FRONTENDS.group}
    assert recorded_plugins() == {"controllers": {}, "frontends": {}}
    _distribution(site, "demo-hold", "demo_hold", {"controller": HOLD},
                  {"expoctl.controllers": {"hold_ep": "demo_hold.controller"}})
    assert recorded_plugins() == {"controllers": {"hold_ep": "demo-hold 0.1: demo_hold.controller"}, "frontends": {}}


def test_the_dvc_generator_follows_what_the_registries_import():
    """The registries import their built-ins by name, which the dvc.yaml generator cannot see in the code: its table
    of such imports must name the same packages, or a new controller's file would be no stage's dependency."""
    from stages.dvc_yaml import DYNAMIC_IMPORTS

    assert DYNAMIC_IMPORTS["src/expoctl/controllers/registry.py"] == CONTROLLERS.builtin_packages
    assert DYNAMIC_IMPORTS["src/expoctl/features/registry.py"] == FRONTENDS.builtin_packages
