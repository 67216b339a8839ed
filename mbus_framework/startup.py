"""Start-up of ``mbus-run``: numpy's submodules that no run uses load only if used; scipy's docstring notes are cheap.

scipy (1.15 and later) builds its array-API namespace with ``from numpy import *``, which imports
every numpy submodule named in ``numpy.__all__``: ``numpy.f2py`` (and with it charset_normalizer),
``numpy.testing`` (and unittest), ``numpy.polynomial``, ``numpy.ctypeslib``, ``numpy.rec``,
``numpy.char`` and ``numpy.strings`` among them, about 0.1 s of CPU at every start-up for modules
a run does not use. :func:`defer_unused_numpy` registers them as lazy modules
(:class:`importlib.util.LazyLoader`): the names exist, and a module runs on its first attribute
access, so code that does use one gets the real module. (``numpy.ma``, ``numpy.random``,
``numpy.fft``, ``numpy.linalg`` and ``numpy.typing`` are used: ``np.median`` asks ``numpy.ma``.)

:func:`cheap_array_api_notes` makes the array-API note scipy adds to about 200 docstrings at import
cheap (the same note in the same Notes section, without re-parsing each docstring). Both are
process-local and applied by the ``mbus-run`` command only, never on ``import mbus_framework``.
"""
from __future__ import annotations

import inspect
import re
import sys

#: numpy submodules that ``from numpy import *`` loads and a run does not use.
UNUSED_NUMPY = ("numpy.f2py", "numpy.testing", "numpy.polynomial", "numpy.ctypeslib", "numpy.rec", "numpy.char",
                "numpy.strings")


def defer_unused_numpy(names: tuple[str, ...] = UNUSED_NUMPY) -> list[str]:
    """Make the numpy submodules ``names`` lazy (imports numpy); returns those made lazy (not the
    ones already loaded or not found)."""
    return [name for name in names if _defer(name)]


def _defer(name: str) -> bool:
    if name in sys.modules:
        return False
    try:
        import importlib.util

        import numpy

        spec = importlib.util.find_spec(name)
        if spec is None or spec.loader is None:
            return False
        spec.loader = importlib.util.LazyLoader(spec.loader)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
        # what ``import numpy.<name>`` would bind (numpy's __getattr__ is not asked)
        setattr(numpy, name.rpartition(".")[2], module)
        return True
    except Exception:  # noqa: BLE001 - an optimisation only: never stop a run
        sys.modules.pop(name, None)
        return False


# --- scipy's array-API notes ------------------------------------------------------------------------

#: a numpydoc section heading (dedented docstring): a title line underlined by dashes
_HEADING = re.compile(r"^([A-Z][A-Za-z ]*)[ \t]*\n[ \t]*-{3,}[ \t]*$", re.MULTILINE)


def cheap_array_api_notes() -> bool:
    """Let scipy's ``xp_capabilities`` decorator add its array-API note without re-parsing.

    scipy (1.15 and later) decorates about 280 functions of scipy.special, scipy.fft, scipy.linalg
    and scipy.optimize with ``xp_capabilities``, which parses each docstring with numpydoc's
    ``FunctionDoc`` at import only to append a note to the Notes section and render the docstring
    anew: about 0.1 s of CPU at every start-up of a run. This swaps the ``FunctionDoc`` that
    decorator uses (and only that one) for :class:`_NoteInserter`, which puts the same note at the
    end of the Notes section of the docstring as written (a new Notes section before References
    and Examples if there is none), so ``help()`` still shows it. Process-local: applied by the
    ``mbus-run`` command before scipy's submodules load, never by ``import mbus_framework``.
    Imports scipy._lib._array_api. Returns False, and changes nothing, when scipy is missing or its
    decorator is not the one this was written for (the check reads the decorator's code), so scipy
    then does what it always did."""
    try:
        from scipy._lib import _array_api, _docscrape
    except Exception:  # noqa: BLE001 - an optimisation only: never stop a run
        return False
    if _array_api.__dict__.get("FunctionDoc") is _NoteInserter:
        return True
    if not _decorator_as_expected(_array_api, _docscrape):
        return False
    _array_api.FunctionDoc = _NoteInserter
    return True


def _decorator_as_expected(array_api, docscrape) -> bool:
    """scipy's decorator does ``doc = FunctionDoc(f); doc['Notes'].append(note);
    str(doc).split("\\n", 1)[1]`` (the code this fast path stands in for)."""
    if array_api.__dict__.get("FunctionDoc") is not getattr(docscrape, "FunctionDoc", None):
        return False
    code = getattr(array_api.__dict__.get("xp_capabilities"), "__code__", None)
    inner = [c for c in getattr(code, "co_consts", ()) if getattr(c, "co_name", None) == "decorator"]
    return len(inner) == 1 and {"FunctionDoc", "append", "split", "__doc__"} <= set(inner[0].co_names) \
        and {"Notes", "\n", 1} <= set(inner[0].co_consts)


class _NoteInserter:
    """What ``xp_capabilities`` asks of ``FunctionDoc(f)``: ``doc['Notes']`` (a list the note is
    appended to) and ``str(doc)`` (a header line, then the docstring with the notes)."""

    def __init__(self, func):
        self._doc = inspect.getdoc(func) or ""
        self._notes: list[str] = []

    def __getitem__(self, key: str) -> list[str]:
        if key != "Notes":
            raise KeyError(key)
        return self._notes

    def __str__(self) -> str:
        text = self._doc
        for note in self._notes:
            text = insert_note(text, note)
        return "\n" + text  # the decorator drops the first line (FunctionDoc's ``.. function::`` header)


def insert_note(doc: str, note: str) -> str:
    """``doc`` (a dedented numpydoc docstring) with ``note`` at the end of its Notes section, or in
    a new Notes section before References or Examples (or at the end) if it has none."""
    note = note.strip("\n")
    headings = [(m.group(1).strip(), m.start()) for m in _HEADING.finditer(doc)]
    names = [name for name, _ in headings]
    if "Notes" in names:
        later = headings[names.index("Notes") + 1:]
        at = later[0][1] if later else len(doc)
    else:
        at = next((start for name, start in headings if name in ("References", "Examples")), len(doc))
        note = f"Notes\n-----\n{note}"
    parts = [doc[:at].rstrip(), note, doc[at:].strip("\n")]
    return "\n\n".join(part for part in parts if part) + "\n"
