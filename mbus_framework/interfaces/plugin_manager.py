"""Build the pluggy plugin manager: every plugin, built-in or third-party, via entry points.

Built-ins in ``plugins/`` are declared in our own ``pyproject.toml`` under the entry-point
group ``mbus_framework``, exactly as a third-party package declares its plugins. A plugin
that fails to import or to register (whatever it raises, ``sys.exit()`` included) is reported
(``manager.broken``) and skipped; it never takes the run down.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from importlib import metadata
from typing import Iterable

import pluggy

from mbus_framework.errors import one_line
from mbus_framework.interfaces.hookspecs import PROJECT, MbusHookSpecs


@dataclass(frozen=True)
class BrokenPlugin:
    """An entry point that could not be loaded or registered."""

    name: str
    source: str
    error: str


class MbusPluginManager(pluggy.PluginManager):
    """A pluggy manager that remembers where each plugin came from and which ones broke."""

    def __init__(self) -> None:
        super().__init__(PROJECT)
        self.add_hookspecs(MbusHookSpecs)
        self.broken: list[BrokenPlugin] = []
        self.sources: dict[str, str] = {}

    def register_plugin(self, plugin: object, name: str, source: str) -> None:
        """Register ``plugin`` under ``name``; record failures instead of raising."""
        try:
            self.register(plugin, name=name)
        except (Exception, SystemExit) as exc:  # noqa: BLE001 - a third-party plugin may raise anything
            # pluggy may have registered the name and the hooks checked before the bad one.
            if self.has_plugin(name):
                self.unregister(name=name)
            self.broken.append(BrokenPlugin(name, source, one_line_error(exc)))
            return
        self.sources[name] = source

    def load_entry_points(self, group: str = PROJECT) -> None:
        for ep in _entry_points(group):
            dist = getattr(ep, "dist", None)
            source = f"{dist.name} {dist.version}" if dist is not None else "(unknown distribution)"
            source = one_line(f"{source} [{ep.value}]", 120)  # shown in listings and one-line errors
            if self.has_plugin(ep.name) or self.is_blocked(ep.name):
                continue
            try:
                plugin = ep.load()
            except (Exception, SystemExit) as exc:  # noqa: BLE001 - even sys.exit() in its import
                self.broken.append(BrokenPlugin(ep.name, source, one_line_error(exc)))
                continue
            self.register_plugin(plugin, ep.name, source)


def one_line_error(exc: BaseException) -> str:
    """``Type: message`` folded onto one line (pluggy's validation errors span several), at most
    300 characters."""
    return one_line(f"{type(exc).__name__}: {exc}", 300)


def _entry_points(group: str) -> Iterable[metadata.EntryPoint]:
    seen = set()
    for ep in metadata.entry_points(group=group):
        key = (ep.name, ep.value)
        if key not in seen:
            seen.add(key)
            yield ep


def new_plugin_manager(extra_plugins: Iterable[tuple[str, object]] = (), entry_points: bool = True) -> MbusPluginManager:
    """A fresh manager: entry points (built-ins and third party), then ``extra_plugins``."""
    pm = MbusPluginManager()
    if entry_points:
        pm.load_entry_points()
    for name, plugin in extra_plugins:
        pm.register_plugin(plugin, name, "registered in code")
    return pm


@functools.lru_cache(maxsize=1)
def get_plugin_manager() -> MbusPluginManager:
    """The process-wide manager (cached)."""
    return new_plugin_manager()
