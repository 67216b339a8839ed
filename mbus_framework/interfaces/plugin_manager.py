"""Build the pluggy plugin manager: every plugin, built-in or third-party, via entry points.

Built-ins in ``plugins/`` are declared in our own ``pyproject.toml`` under the entry-point
group ``mbus_framework``, exactly as a third-party package declares its plugins. A plugin
that fails to import or to register (whatever it raises, ``sys.exit()`` included) is reported
(``manager.broken``) and skipped; it never takes the run down.

A plugin module whose package declares the names it registers (``MBUS_PLUGIN_NAMES`` in the
package's ``__init__``: ``{module: {kind: names}}``, as ``mbus_plugins`` does) is not imported
up front: the manager keeps its entry point in ``deferred`` and
:class:`~mbus_framework.interfaces.registry.Registry` loads it (:meth:`MbusPluginManager.load_deferred`)
when one of those names is asked for, or for a full listing.
"""
from __future__ import annotations

import functools
import importlib
from dataclasses import dataclass
from importlib import metadata
from typing import Iterable

import pluggy

from mbus_framework.errors import one_line
from mbus_framework.interfaces.hookspecs import HOOKS_BY_KIND, PROJECT, MbusHookSpecs

#: Attribute of a plugin package's ``__init__`` declaring the names of its modules (see above).
DECLARATION = "MBUS_PLUGIN_NAMES"


@dataclass(frozen=True)
class BrokenPlugin:
    """An entry point that could not be loaded or registered."""

    name: str
    source: str
    error: str


@dataclass(frozen=True)
class DeferredPlugin:
    """An entry point not imported yet, and the names (kind -> names) its package says it registers."""

    entry_point: metadata.EntryPoint
    source: str
    names: dict[str, tuple[str, ...]]


class MbusPluginManager(pluggy.PluginManager):
    """A pluggy manager that remembers where each plugin came from and which ones broke."""

    def __init__(self) -> None:
        super().__init__(PROJECT)
        self.add_hookspecs(MbusHookSpecs)
        self.broken: list[BrokenPlugin] = []
        self.sources: dict[str, str] = {}
        self.deferred: dict[str, DeferredPlugin] = {}  # entry-point name -> not yet imported

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

    def load_entry_points(self, group: str = PROJECT, lazy: bool = True) -> None:
        """Register the plugins of the entry-point ``group``; with ``lazy``, those whose names are
        declared (:func:`declared_names`) are only noted in :attr:`deferred`."""
        distributions: dict[int, str] = {}  # id(distribution) -> "name version"
        for ep in _entry_points(group):
            dist = getattr(ep, "dist", None)
            if id(dist) not in distributions:
                distributions[id(dist)] = _distribution(dist)
            source = one_line(f"{distributions[id(dist)]} [{ep.value}]", 120)  # shown in listings and one-line errors
            if self.has_plugin(ep.name) or self.is_blocked(ep.name) or ep.name in self.deferred:
                continue
            names = declared_names(ep) if lazy else None
            if names:
                self.deferred[ep.name] = DeferredPlugin(ep, source, names)
            else:
                self._load(ep, source)

    def load_deferred(self, name: str) -> None:
        """Import and register the deferred plugin ``name`` (a failure lands in :attr:`broken`)."""
        plugin = self.deferred.pop(name, None)
        if plugin is not None and not (self.has_plugin(name) or self.is_blocked(name)):
            self._load(plugin.entry_point, plugin.source)

    def _load(self, ep: metadata.EntryPoint, source: str) -> None:
        try:
            plugin = ep.load()
        except (Exception, SystemExit) as exc:  # noqa: BLE001 - even sys.exit() in its import
            self.broken.append(BrokenPlugin(ep.name, source, one_line_error(exc)))
            return
        self.register_plugin(plugin, ep.name, source)


def _distribution(dist: metadata.Distribution | None) -> str:
    """``name version`` of ``dist``: its metadata parsed once (``dist.name`` and ``dist.version``
    parse the whole METADATA file each, about 1.5 ms a time)."""
    if dist is None:
        return "(unknown distribution)"
    meta = dist.metadata
    return f"{meta['Name']} {meta['Version']}"


def declared_names(ep: metadata.EntryPoint) -> dict[str, tuple[str, ...]] | None:
    """kind -> names that the module of ``ep`` registers, from its top-level package's
    :data:`DECLARATION`; None when the package declares nothing usable for it (then the module is
    imported at once, as any plugin; a package that fails to import is reported that way too)."""
    module = ep.value.strip()
    top = module.partition(".")[0]
    if ":" in module or top == module:
        return None
    try:
        table = getattr(importlib.import_module(top), DECLARATION, None)
    except (Exception, SystemExit):  # noqa: BLE001 - loaded (and reported as broken) the usual way
        return None
    entry = table.get(module) if isinstance(table, dict) else None
    if not (isinstance(entry, dict) and entry and set(entry) <= set(HOOKS_BY_KIND)):
        return None
    names = {kind: tuple(entry[kind]) for kind in entry if not isinstance(entry[kind], str)}
    if len(names) != len(entry) or not all(isinstance(n, str) for v in names.values() for n in v):
        return None
    return names


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


def new_plugin_manager(extra_plugins: Iterable[tuple[str, object]] = (), entry_points: bool = True,
                       lazy: bool = True) -> MbusPluginManager:
    """A fresh manager: entry points (built-ins and third party; with ``lazy``, declared ones
    deferred), then ``extra_plugins``."""
    pm = MbusPluginManager()
    if entry_points:
        pm.load_entry_points(lazy=lazy)
    for name, plugin in extra_plugins:
        pm.register_plugin(plugin, name, "registered in code")
    return pm


@functools.lru_cache(maxsize=1)
def get_plugin_manager() -> MbusPluginManager:
    """The process-wide manager (cached)."""
    return new_plugin_manager()
