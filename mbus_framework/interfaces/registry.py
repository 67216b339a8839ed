"""Registry: the implementations the plugin manager collected, looked up by kind and name.

Failures stay with the plugin that caused them: a plugin whose hook raises (or calls
``sys.exit``) or returns bad records is listed in ``broken`` and skipped; a name registered by
two plugins is listed in ``clashes`` and only *that name* is unusable (asking for it explains
the clash), so every other plugin and ``--list-plugins`` keep working. Asking for an unknown
name also names the plugins that failed to load, since one of them may be the provider.

Plugins whose names are declared (:func:`~mbus_framework.interfaces.plugin_manager.declared_names`)
are imported when one of their names is asked for (:meth:`Registry.get`); :meth:`Registry.names`
lists them without importing, and :attr:`Registry.entries` (``--list-plugins``) imports them all.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable

from mbus_framework.errors import PluginError, one_line, shown
from mbus_framework.interfaces.hookspecs import HOOKS_BY_KIND, SPEC_BY_KIND, PluginSpec
from mbus_framework.interfaces.plugin_manager import BrokenPlugin, MbusPluginManager, get_plugin_manager, one_line_error
from mbus_framework.suggest import choices_text, did_you_mean

KIND_BASES = {
    "model": ("mbus_framework.interfaces.model", "MediumModel"),
    "excitation": ("mbus_framework.interfaces.excitation", "Excitation"),
    "solver": ("mbus_framework.estimation.problem", "Solver"),
    "compensator": ("mbus_framework.interfaces.compensator", "Compensator"),
    "backend": ("mbus_framework.interfaces.backend", "Backend"),
}


#: Longest plugin name accepted: a name is typed in configs and printed in one-line messages.
MAX_NAME = 64


@dataclass(frozen=True)
class Entry:
    spec: PluginSpec
    plugin: str  # registering plugin name (entry-point name)
    source: str  # distribution / where it came from


@dataclass
class Registry:
    loaded: dict[str, dict[str, Entry]] = field(default_factory=dict)
    broken: list[BrokenPlugin] = field(default_factory=list)
    clashes: dict[tuple[str, str], str] = field(default_factory=dict)
    manager: MbusPluginManager | None = None
    #: (kind, name) -> the deferred plugins (entry-point names) that declare it, not imported yet
    deferred: dict[tuple[str, str], list[str]] = field(default_factory=dict)

    @classmethod
    def from_manager(cls, pm: MbusPluginManager) -> "Registry":
        reg = cls({kind: {} for kind in HOOKS_BY_KIND}, list(pm.broken), manager=pm)
        reg._collect(pm.get_plugins())
        for plugin_name, plugin in pm.deferred.items():
            for kind, names in plugin.names.items():
                for name in names:
                    reg.deferred.setdefault((kind, name), []).append(plugin_name)
        # a declared name that a loaded plugin registers too, or that two deferred plugins
        # declare, is a clash: load its providers now so that it is reported as one
        for (kind, name), providers in list(reg.deferred.items()):
            if len(providers) > 1 or name in reg.loaded[kind]:
                reg._load(kind, name)
        return reg

    @property
    def entries(self) -> dict[str, dict[str, Entry]]:
        """kind -> name -> :class:`Entry` of every plugin (deferred ones are imported now)."""
        self.load_all()
        return self.loaded

    def load_all(self) -> None:
        """Import every deferred plugin (for a full listing)."""
        for kind, name in list(self.deferred):
            self._load(kind, name)

    def _load(self, kind: str, name: str) -> None:
        """Import the deferred plugins that declare ``kind`` ``name`` and add what they register."""
        providers = self.deferred.pop((kind, name), [])
        if not providers or self.manager is None:
            return
        pm = self.manager
        fresh = []
        for plugin_name in providers:
            pm.load_deferred(plugin_name)  # a no-op when another registry of this manager loaded it
            plugin = pm.get_plugin(plugin_name)
            if plugin is not None:
                fresh.append(plugin)
            else:
                self.broken += [b for b in pm.broken if b.name == plugin_name and b not in self.broken]
        for plugin_name in providers:  # their other declared names come with them
            for key in [k for k, v in self.deferred.items() if plugin_name in v]:
                self.deferred[key].remove(plugin_name)
                if not self.deferred[key]:
                    del self.deferred[key]
        self._collect(fresh)

    def _collect(self, plugins: Iterable[object]) -> None:
        """Add the specs that the hooks of ``plugins`` return (a failing hook: a broken plugin)."""
        import importlib

        pm = self.manager
        wanted = set(map(id, plugins))
        for kind, hook_name in HOOKS_BY_KIND.items():
            module, base_name = KIND_BASES[kind]
            base = getattr(importlib.import_module(module), base_name)
            for impl in getattr(pm.hook, hook_name).get_hookimpls():
                if id(impl.plugin) not in wanted:
                    continue
                plugin_name = pm.get_name(impl.plugin) or "?"
                source = pm.sources.get(plugin_name, "registered in code")
                try:
                    specs = list(impl.function() or [])
                    for spec in specs:
                        _check_spec(spec, kind, base)
                except (Exception, SystemExit) as exc:  # noqa: BLE001 - report and skip the broken plugin
                    self.broken.append(BrokenPlugin(plugin_name, source, f"{hook_name}: {one_line_error(exc)}"))
                    continue
                for spec in specs:
                    self._add(kind, Entry(spec, plugin_name, source))

    def _add(self, kind: str, entry: Entry) -> None:
        name = entry.spec.name
        if (kind, name) in self.clashes:
            self.clashes[kind, name] += f" and by {entry.plugin} ({entry.source})"
            return
        first = self.loaded[kind].pop(name, None)
        if first is None:
            self.loaded[kind][name] = entry
            return
        self.clashes[kind, name] = (f"{kind} {shown(name)} is registered twice: by {first.plugin} ({first.source}) "
                                    f"and by {entry.plugin} ({entry.source})")

    def names(self, kind: str) -> list[str]:
        """The usable names of ``kind``, deferred ones included (nothing is imported)."""
        return sorted({*self.loaded[kind], *(n for k, n in self.deferred if k == kind)})

    def get(self, kind: str, name: str) -> PluginSpec:
        try:
            if (kind, name) in self.deferred:
                self._load(kind, name)
            return self.loaded[kind][name].spec
        except (KeyError, TypeError):
            pass
        if (kind, name) in self.clashes:
            raise PluginError(f"{self.clashes[kind, name]}; uninstall or block one of them")
        choices = self.names(kind)
        hint = did_you_mean(name, choices) if isinstance(name, str) and len(name) <= 60 else ""
        raise PluginError(f"unknown {kind} {shown(name)}{hint}; choose one of: {choices_text(choices)}"
                          f"{self._broken_hint()}")

    def _broken_hint(self) -> str:
        """Plugins that failed to load may be the missing provider: name them (first three)."""
        if not self.broken:
            return ""
        listed = "; ".join(f"{one_line(b.name, MAX_NAME)} ({shown(b.error, 120)}) [{b.source}]" for b in self.broken[:3])
        more = f" and {len(self.broken) - 3} more" if len(self.broken) > 3 else ""
        return f". Plugins that failed to load (--list-plugins): {listed}{more}"


def _check_spec(spec: object, kind: str, base: type) -> None:
    expected = SPEC_BY_KIND[kind]
    if not isinstance(spec, expected):
        raise TypeError(f"expected {expected.__name__} records, got {type(spec).__name__}")
    name = spec.name
    one_word = isinstance(name, str) and name.isprintable() and len(name.split()) == 1
    if not (one_word and len(name) <= MAX_NAME):
        raise ValueError(f"{kind} name {shown(name, 80)} must be one word of 1-{MAX_NAME} printable characters")
    if not (isinstance(spec.implementation, type) and issubclass(spec.implementation, base)):
        raise TypeError(f"{spec.name}: implementation must subclass {base.__name__}")


_default: Registry | None = None


def default_registry() -> Registry:
    """Registry over the cached process-wide plugin manager."""
    global _default
    if _default is None:
        _default = Registry.from_manager(get_plugin_manager())
    return _default
