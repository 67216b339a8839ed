"""Safe, bounded YAML for configs and ``--set`` values.

Safe: PyYAML's SafeLoader (no Python object tags), extended to read ``1e-6`` and ``6.0e8`` as
floats (YAML 1.1 wants ``1.0e-6``, ``6.0e+8``). Bounded, so that no config can hang or exhaust
the machine:

* nesting at most :data:`MAX_DEPTH` levels, checked on the event stream (PyYAML's parser is
  iterative; its composer and constructor recurse, and 1000 levels overflow Python's stack);
* at most :data:`MAX_NODES` nodes after alias expansion, counted on the node graph before
  anything is constructed (a 1 KB "billion laughs" of nested aliases expands to gigabytes);
  recursive aliases are refused;
* a tag's value that does not convert (``!!float abc``, ``!!int 1.5``, ``!!timestamp x``, on
  which PyYAML itself raises AttributeError) is a YAML error, not a Python exception.

The file itself is read by :func:`read_config_text` (regular files of at most
:data:`MAX_CONFIG_BYTES`, UTF-8 or UTF-16 with a byte-order mark).
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml
from yaml.events import CollectionEndEvent, CollectionStartEvent

from mbus_framework.errors import ConfigError
from mbus_framework.pipeline.storage import read_regular_file

MAX_CONFIG_BYTES = 1 << 20
"""Largest config file [bytes] (the shipped ones are 1-3 KB)."""
MAX_DEPTH = 64
"""Deepest nesting of mappings and sequences (the shipped configs use 5)."""
MAX_NODES = 100_000
"""Most nodes after alias expansion (the shipped configs have about 100)."""


class ConfigLoader(yaml.SafeLoader):
    """Safe loader that also reads 1e-6 and 6.0e8 as floats (YAML 1.1 wants 1.0e-6, 6.0e+8)."""


ConfigLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(
        r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
        |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
        |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
        |[-+]?\.(?:inf|Inf|INF)
        |\.(?:nan|NaN|NAN))$""",
        re.X,
    ),
    list("-+0123456789."),
)


class LimitError(yaml.YAMLError):
    """A YAML document beyond the loader's bounds, or a tag value that does not convert."""

    def __init__(self, problem: str, mark=None) -> None:
        super().__init__(problem)
        self.problem = problem
        self.problem_mark = mark


def yaml_load(text: str) -> Any:
    """Parse YAML text within the bounds of the module docstring; problems are yaml.YAMLError."""
    depth = 0
    for event in yaml.parse(text, Loader=ConfigLoader):
        if isinstance(event, CollectionStartEvent):
            depth += 1
            if depth > MAX_DEPTH:
                raise LimitError(f"nested deeper than {MAX_DEPTH} levels", event.start_mark)
        elif isinstance(event, CollectionEndEvent):
            depth -= 1
    loader = ConfigLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        size = _expanded_size(node, {}, set())
        if size > MAX_NODES:
            raise LimitError(f"expands to {size:,} values through aliases (more than {MAX_NODES:,})", node.start_mark)
        try:
            return loader.construct_document(node)
        except yaml.YAMLError:
            raise
        except Exception as exc:  # noqa: BLE001 - PyYAML's constructors raise anything on bad tagged scalars
            raise LimitError(f"a tagged value does not convert ({type(exc).__name__}: {str(exc)[:100]})") from None
    finally:
        loader.dispose()


def _expanded_size(node: yaml.Node, sizes: dict[int, int], open_nodes: set[int]) -> int:
    """Nodes under ``node`` counting every alias use again; shared sub-graphs are sized once."""
    key = id(node)
    if key in sizes:
        return sizes[key]
    if key in open_nodes:
        raise LimitError("a recursive alias (an anchor used inside itself)", node.start_mark)
    open_nodes.add(key)
    total = 1
    if isinstance(node, yaml.SequenceNode):
        total += sum(_expanded_size(child, sizes, open_nodes) for child in node.value)
    elif isinstance(node, yaml.MappingNode):
        total += sum(_expanded_size(k, sizes, open_nodes) + _expanded_size(v, sizes, open_nodes)
                     for k, v in node.value)
    open_nodes.discard(key)
    sizes[key] = min(total, MAX_NODES + 1)
    return sizes[key]


def read_config_text(path: str | Path) -> str:
    """A config file's text: a regular file, at most MAX_CONFIG_BYTES, UTF-8 (BOM allowed) or UTF-16 with BOM."""
    data = read_regular_file(path, "config file", MAX_CONFIG_BYTES, ConfigError)
    if data[:2] in (b"\xff\xfe", b"\xfe\xff"):
        encoding = "utf-16"
    else:
        encoding = "utf-8-sig"
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not UTF-8 text (byte {data[exc.start:exc.start + 1]!r} at offset {exc.start}); "
                          f"save the config as UTF-8") from None


def describe_yaml_error(exc: yaml.YAMLError) -> str:
    """'invalid YAML at line L, column C: problem' in one line."""
    mark = getattr(exc, "problem_mark", None)
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
    problem = getattr(exc, "problem", None) or (str(exc).splitlines() or ["unknown problem"])[0]
    return f"invalid YAML{where}: {problem}"
