"""The plugin lookup of the controller registry: names other packages register under the entry-point
group m2h_ros.controllers, and the errors that name a bad registration (the end-to-end install is
test/graph/test_controller_plugin.py)."""

from importlib.metadata import EntryPoint

import pytest

from m2h_ros.agents import registry
from m2h_ros.agents.baselines import StandInPlace
from m2h_ros.errors import ConfigError


def with_entry_points(monkeypatch, *points: tuple[str, str]) -> None:
    found = [EntryPoint(name, value, registry.PLUGIN_GROUP) for name, value in points]
    monkeypatch.setattr(registry, "entry_points", lambda group: found if group == registry.PLUGIN_GROUP else [])


def test_a_registered_controller_is_found_and_made(monkeypatch):
    with_entry_points(monkeypatch, ("standing_plugin", "m2h_ros.agents.baselines:StandInPlace"))
    monkeypatch.setattr(registry, "PLUGINS", registry._plugins())
    assert registry.PLUGINS == {"standing_plugin": "m2h_ros.agents.baselines:StandInPlace"}
    controller = registry.make_controller("standing_plugin", 2, seed=3)
    assert isinstance(controller, StandInPlace) and controller.n_slots == 2 and controller.seed == 3


@pytest.mark.parametrize("points, message", [
    ((("doa", "pkg:Cls"),), "reuses the controller name 'doa'"),
    ((("twice", "a:B"), ("twice", "c:D")), "reuses the controller name 'twice'"),
    ((("bad:name", "a:B"),), "must read NAME"),
    ((("no_class", "just_a_module"),), "must read NAME"),
])
def test_a_bad_registration_is_named(monkeypatch, points, message):
    with_entry_points(monkeypatch, *points)
    with pytest.raises(ConfigError, match=message):
        registry._plugins()


@pytest.mark.parametrize("target, message", [
    ("m2h_ros.no_such_module:Cls", "cannot load"),
    ("m2h_ros.agents.baselines:NoSuchClass", "cannot load"),
    ("m2h_ros.errors:ConfigError", "is not a subclass of m2h_ros.agents.base.Controller"),
])
def test_a_plugin_that_does_not_load_as_a_controller_is_named(monkeypatch, target, message):
    monkeypatch.setattr(registry, "PLUGINS", {"broken_plugin": target})
    with pytest.raises(ConfigError, match=f"controller 'broken_plugin': .*{message}"):
        registry.controller_class("broken_plugin")
