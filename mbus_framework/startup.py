"""Start-up of ``mbus-run``: what a run does not use is not loaded, and loading is cheaper.

All of it is process-local and applied by the ``mbus-run`` command only (``cli._prestart`` and
``cli._main``), never on ``import mbus_framework``; each part falls back to the usual behaviour
when numpy's or scipy's internals are not what it expects.

- :func:`defer_unused_numpy`: scipy (1.15 and later) builds its array-API namespace with
  ``from numpy import *``, which imports every numpy submodule in ``numpy.__all__``:
  ``numpy.f2py`` (and with it charset_normalizer), ``numpy.testing`` (and unittest),
  ``numpy.polynomial``, ``numpy.ctypeslib``, ``numpy.rec``, ``numpy.char`` and ``numpy.strings``,
  about 0.1 s of CPU. They become lazy modules (:class:`importlib.util.LazyLoader`): the names
  exist, and a module runs on its first attribute access, so code that uses one gets the real
  module. (``numpy.ma``, ``.random``, ``.fft``, ``.linalg`` and ``.typing`` are used: ``np.median``
  asks ``numpy.ma``.)
- :func:`defer_unused_scipy`: the same for scipy.spatial, which scipy.optimize imports for
  ``shgo`` only (with scipy.constants, about 0.04 s).
- :func:`cheap_scipy_notes`: scipy's decorators add a note to about 270 docstrings at import by
  re-parsing each one with numpydoc (about 0.1 s); the same note goes into the same section
  without the parse.
- :func:`collector_paused`: no cyclic garbage collection while the run's modules load (about
  0.02 s).
"""
from __future__ import annotations

import gc
import importlib
import re
import sys
import textwrap
from contextlib import contextmanager
from typing import Iterator

#: numpy submodules that ``from numpy import *`` loads and a run does not use.
UNUSED_NUMPY = ("numpy.f2py", "numpy.testing", "numpy.polynomial", "numpy.ctypeslib", "numpy.rec", "numpy.char",
                "numpy.strings")


#: scipy subpackages that scipy.optimize imports (``from scipy import spatial`` in its ``shgo``, and
#: with it scipy.constants) and a run does not use.
UNUSED_SCIPY = ("scipy.spatial",)


def defer_unused_numpy(names: tuple[str, ...] = UNUSED_NUMPY) -> list[str]:
    """Make the numpy submodules ``names`` lazy (imports numpy); returns those made lazy (not the
    ones already loaded or not found)."""
    return [name for name in names if _defer(name)]


def defer_unused_scipy(names: tuple[str, ...] = UNUSED_SCIPY) -> list[str]:
    """Make the scipy subpackages ``names`` lazy (imports scipy's top level only), as
    :func:`defer_unused_numpy` does numpy's; returns those made lazy."""
    return [name for name in names if _defer(name)]


def _defer(name: str) -> bool:
    if name in sys.modules:
        return False
    try:
        import importlib.util

        parent = importlib.import_module(name.rpartition(".")[0])
        spec = importlib.util.find_spec(name)
        if spec is None or spec.loader is None:
            return False
        spec.loader = importlib.util.LazyLoader(spec.loader)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
        # what ``import parent.<name>`` would bind (the parent's module __getattr__ is not asked)
        setattr(parent, name.rpartition(".")[2], module)
        return True
    except Exception:  # noqa: BLE001 - an optimisation only: never stop a run
        sys.modules.pop(name, None)
        return False


@contextmanager
def collector_paused() -> Iterator[None]:
    """Python's cyclic garbage collector off while the block runs (on again after, if it was).

    Loading a run's modules creates some 10^5 long-lived objects (modules, classes, functions,
    pydantic schemas) and next to no cyclic garbage, yet the collector runs about 190 times while
    they load, each time walking the young objects: about 0.02 s of CPU. ``mbus-run`` pauses it
    around its imports only; the fit and everything after run with the collector as usual."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


# --- scipy's docstring notes ------------------------------------------------------------------------

#: a numpydoc section heading's underline: dashes to the end of a line (the title is the line above)
_UNDERLINE = re.compile(r"---+[ \t]*$", re.MULTILINE)
#: a section title (Parameters, See Also, Notes, ...)
_TITLE = re.compile(r"[A-Z][A-Za-z ]*")
#: the indentation of a docstring's second and later lines (the first is not indented)
_INDENT = re.compile(r"\n([ \t]*)\S")

#: scipy's decorators that re-parse a docstring only to add a note: (module, decorator factory,
#: the section the note goes to)
NOTE_DECORATORS = (("scipy._lib._array_api", "xp_capabilities", "Notes"),
                   ("scipy._lib._util", "_apply_over_batch", "Extended Summary"))


def cheap_scipy_notes() -> list[str]:
    """Let scipy's decorators add their docstring notes without re-parsing each docstring.

    scipy (1.15 and later) decorates about 200 functions of scipy.special, .fft, .linalg and
    .optimize with ``xp_capabilities`` (an array-API note in the Notes section), 70 functions
    of scipy.linalg with ``_apply_over_batch`` (a note on batched arguments after the summary)
    and a few of scipy.optimize with ``_transition_to_rng`` (a new description of the ``rng``
    parameter). Each parses the docstring with numpydoc's ``FunctionDoc`` at import, only to make
    that change and render the docstring anew: about 0.15 s of CPU at every start-up of a run.
    This swaps the ``FunctionDoc`` of the decorators' two modules for :class:`_NoteInserter`,
    which makes the same change in the docstring as written (``help()`` shows it; the
    ``rng`` rewrite reads only the Parameters section) and hands anything else asked of it to
    the real ``FunctionDoc``.

    Process-local: applied by the ``mbus-run`` command before scipy's submodules load, never by
    ``import mbus_framework``. Returns the modules changed; a module whose decorator is not the one
    this was written for (the check reads the decorator's code) is left alone, and scipy then does
    what it always did there."""
    done = []
    for module_name, factory, section in NOTE_DECORATORS:
        try:
            module = importlib.import_module(module_name)
            from scipy._lib import _docscrape
        except Exception:  # noqa: BLE001 - an optimisation only: never stop a run
            continue
        if module.__dict__.get("FunctionDoc") is _NoteInserter or _decorator_as_expected(
                module.__dict__, factory, section, _docscrape):
            module.FunctionDoc = _NoteInserter
            done.append(module_name)
    return done


def _decorator_as_expected(namespace: dict, factory: str, section: str, docscrape) -> bool:
    """The decorator ``namespace[factory]`` returns does ``doc = FunctionDoc(f);
    doc[section].append(note); ... str(doc).split("\\n", 1)[1]`` with scipy's own ``FunctionDoc``
    (the code this fast path stands in for)."""
    if namespace.get("FunctionDoc") is not getattr(docscrape, "FunctionDoc", None):
        return False
    code = getattr(namespace.get(factory), "__code__", None)
    inner = [c for c in getattr(code, "co_consts", ()) if getattr(c, "co_name", None) == "decorator"]
    return len(inner) == 1 and {"FunctionDoc", "append", "split", "__doc__"} <= set(inner[0].co_names) \
        and {section, "\n", 1} <= set(inner[0].co_consts)


class _NoteInserter:
    """What the decorators ask of ``FunctionDoc(f)``, without parsing the whole docstring:
    ``doc[section]`` (a list a note is appended to), ``doc["Parameters"]`` (the parameters, whose
    entries may be replaced: scipy's ``rng`` note) and ``str(doc)`` (a header line, then the
    docstring with the notes and replaced entries). Anything else is handed to scipy's
    ``FunctionDoc``, built then, with what was added so far."""

    SECTIONS = ("Notes", "Extended Summary")

    def __init__(self, func, *args, **kwargs):
        self._func, self._args, self._kwargs = func, args, kwargs
        self._added: dict[str, list[str]] = {}
        self._params: list | None = None  # what doc["Parameters"] handed out, and as parsed
        self._parsed: list = []
        self._full = None

    def _real(self):
        if self._full is None:
            from scipy._lib._docscrape import FunctionDoc

            self._full = FunctionDoc(self._func, *self._args, **self._kwargs)
            for section, notes in self._added.items():
                self._full[section] += notes
            if self._params is not None:
                self._full["Parameters"] = list(self._params)
        return self._full

    def __getitem__(self, key: str):
        if self._full is None and not self._args and not self._kwargs:
            if key in self.SECTIONS and self._params is None:
                return self._added.setdefault(key, [])
            if key == "Parameters" and not self._added:
                if self._params is None:
                    self._parsed = _parameters(_getdoc(self._func))
                    self._params = [param for param, _, _ in self._parsed]
                return self._params
        return self._real()[key]

    def __setitem__(self, key: str, value) -> None:
        self._real()[key] = value

    def __str__(self) -> str:
        if self._full is not None:
            return str(self._full)
        if self._params is not None:
            return "\n" + self._with_parameters()
        text = getattr(self._func, "__doc__", None) or ""
        for section, notes in self._added.items():
            for note in notes:
                text = insert_note(text, note, section)
        return "\n" + text  # the decorators drop the first line (FunctionDoc's ``.. function::`` header)

    def _with_parameters(self) -> str:
        """The docstring (dedented, as scipy's rendering is) with the replaced parameter entries."""
        if len(self._params) != len(self._parsed):
            return str(self._real()).split("\n", 1)[1]
        lines = _getdoc(self._func).split("\n")
        for param, (parsed, first, last) in reversed(list(zip(self._params, self._parsed))):
            if param is not parsed:
                entry = [" : ".join(part for part in (param.name, param.type) if part)]
                if param.desc and "".join(param.desc).strip():
                    entry += ["    " + line for line in param.desc]  # scipy's rendering: four spaces
                lines[first:last] = entry
        return "\n".join(lines)


def _getdoc(func) -> str:
    import inspect

    return inspect.getdoc(func) or ""


def _parameters(doc: str) -> list:
    """The Parameters section of a dedented numpydoc docstring as numpydoc reads it: [(Parameter,
    first line, end line)] (the entry's lines, its trailing blank lines left out)."""
    from scipy._lib._docscrape import Parameter

    headings = _headings(doc)
    names = [name for name, _, _ in headings]
    if "Parameters" not in names:
        return []
    i = names.index("Parameters")
    start = doc.count("\n", 0, headings[i][1]) + 2  # the line after the dashes
    lines = doc.split("\n")
    stop = doc.count("\n", 0, headings[i + 1][1]) if i + 1 < len(headings) else len(lines)
    # numpydoc takes the section's first line as an entry's header however it is indented, then
    # each unindented line after it
    filled = [n for n in range(start, stop) if lines[n].strip()]
    headers = filled[:1] + [n for n in filled[1:] if not lines[n][0].isspace()]
    found = []
    for k, n in enumerate(headers):
        end = headers[k + 1] if k + 1 < len(headers) else stop
        while end > n + 1 and not lines[end - 1].strip():
            end -= 1
        header = lines[n].strip()
        name, _, kind = header.partition(" : ") if " : " in header else (header.removesuffix(" :"), "", "")
        desc = textwrap.dedent("\n".join(lines[n + 1:end])).split("\n") if end > n + 1 else []
        while desc and not desc[0].strip():
            desc.pop(0)
        found.append((Parameter(name, kind, desc), n, end))
    return found


def insert_note(doc: str, note: str, section: str = "Notes") -> str:
    """``doc`` (a numpydoc docstring as written) with ``note`` added to ``section``, indented as
    the section headings are, so that :func:`inspect.getdoc` shows it as part of the docstring.

    Notes: at the end of the Notes section, or in a new one before References or Examples (or at
    the end). Extended Summary: before the first section heading (or at the end)."""
    headings = _headings(doc)
    names = [name for name, _, _ in headings]
    if section == "Extended Summary":
        after = headings[:1]
    elif "Notes" in names:
        after = headings[names.index("Notes") + 1:][:1] or [(None, len(doc), headings[names.index("Notes")][2])]
    else:
        after = [h for h in headings if h[0] in ("References", "Examples")][:1]
        note = f"Notes\n-----\n{note.strip(chr(10))}"
    if after:
        at, indent = after[0][1], after[0][2]
    else:
        indent = headings[0][2] if headings else min(_INDENT.findall(doc), key=len, default="")
        at = len(doc)
    note = "\n".join(indent + line if line.strip() else "" for line in note.strip("\n").split("\n"))
    parts = [doc[:at].rstrip(), note, doc[at:].lstrip("\n")]
    text = "\n\n".join(part for part in parts if part.strip())
    return text if parts[2].strip() else text + "\n"  # the docstring's own ending, or the note's


def _headings(doc: str) -> list[tuple[str, int, str]]:
    """(title, start of the title line, indentation) of each numpydoc section heading: a title
    line, and under it a line of dashes, both as indented as the docstring."""
    found = []
    for m in _UNDERLINE.finditer(doc):
        line = doc.rfind("\n", 0, m.start()) + 1
        indent = doc[line:m.start()]
        if line == 0 or indent.strip(" \t"):
            continue
        title_at = doc.rfind("\n", 0, line - 1) + 1
        title = doc[title_at:line - 1].rstrip(" \t")
        if title.startswith(indent) and _TITLE.fullmatch(title, len(indent)):
            found.append((title[len(indent):], title_at, indent))
    return found
