"""Fuzz cases for ``mbus-run``: mutated configs and mutated data files of every format.

A case is built by a *chooser* (every random decision goes through it), so the same code runs
under hypothesis (``HypothesisChooser``: shrinking, the example database) and in the long
seeded campaign (``RandomChooser``). :func:`run_case` runs one case through
``mbus_framework.cli.main`` in-process and checks what issue 15 demands of every run:

* exit 0, or exit 2/3 with exactly one error line naming the config, a data file, the output
  folder or a key (warnings are single lines too), and never a traceback;
* no hang (a per-case time limit);
* every JSON file written is strict JSON (no NaN or Infinity tokens);
* nothing written outside the run folder and the paths the config names;
* an existing calibration file is never replaced without ``--overwrite``.

Exceptions are not caught here: with ``MBUS_DEBUG=1`` (set by the callers) anything but an
``MbusError`` escapes ``main`` and fails the case, so bugs are found, not hidden.
"""
from __future__ import annotations

import copy
import datetime as _dt
import json
import os
import random
import shutil
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import yaml

import reliability_support as rs

# -- choosers --------------------------------------------------------------------------------


class RandomChooser:
    """Decisions from a seeded ``random.Random``."""

    def __init__(self, seed: int) -> None:
        self.rng = random.Random(seed)

    def choice(self, seq: Sequence[Any]) -> Any:
        return seq[self.rng.randrange(len(seq))]

    def integer(self, lo: int, hi: int) -> int:
        return self.rng.randint(lo, hi)

    def chance(self, p: float) -> bool:
        return self.rng.random() < p


class HypothesisChooser:
    """Decisions drawn from hypothesis' ``st.data()`` (so failures shrink)."""

    def __init__(self, data) -> None:
        from hypothesis import strategies as st

        self.data, self.st = data, st

    def choice(self, seq: Sequence[Any]) -> Any:
        return seq[self.data.draw(self.st.integers(0, len(seq) - 1))]

    def integer(self, lo: int, hi: int) -> int:
        return self.data.draw(self.st.integers(lo, hi))

    def chance(self, p: float) -> bool:
        return self.data.draw(self.st.integers(0, 999)) < int(p * 1000)


# -- values ------------------------------------------------------------------------------------
NASTY_NUMBERS = [0, -1, 1, 2, 3, 16, 17, 0.5, -0.5, 1e-3, 2**31, 2**63, -(2**63), 10**100, 1e-300, 5e-324,
                 1e-324, 1e300, -1e300, 1e308, -1e308, float("nan"), float("inf"), float("-inf"), -0.0]
NASTY_STRINGS = ["", " ", "x", "nan", "inf", "-inf", "1e400", "0x10", "1_000", "٣", "∞", "a\nb", "a\x00b",
                 "x" * 10_000, "~", "null", "yes", "../../etc", "-", "2024-01-01", "kelvin_voigt", "prbs"]
NASTY_OTHER = [None, True, False, [], {}, [1, 2], [[1]], {"a": 1}, [float("nan")], {"k_sigma": 1.0},
               _dt.date(2024, 1, 1), [0.0, 0.005]]
PLUGIN_NAMES = {
    "model.name": ["kelvin_voigt", "maxwell", "sls", "generalized_maxwell", "layered"],
    "excitation.name": ["prbs", "multisine", "sine_sweep", "from_file"],
    "backend.name": ["simulated", "file", "lab"],
    "solver.name": ["scipy_lm", "casadi_collocation"],
    "compensator.name": ["none", "transfer_function"],
}
EXTRA_KEYS = [
    "excitation.options.duration", "excitation.options.periods", "excitation.options.inverse_repeat",
    "excitation.options.shift", "excitation.options.quantize", "excitation.options.quantize.bits",
    "excitation.options.quantize.clock", "excitation.options.quantize.full_scale",
    "backend.options.noise.absolute_std", "backend.options.noise.input_relative_std", "backend.options.hold",
    "backend.options.input_gain", "backend.options.delay", "backend.options.medium", "backend.options.medium.name",
    "backend.options.scope", "backend.options.scope.bits", "backend.options.scope.averages",
    "backend.options.scope.trigger_delay", "backend.options.scope.output_range", "backend.options.transducers",
    "backend.options.transducers.centre_frequency", "backend.options.transducers.order", "backend.options.wave",
    "model.initial", "model.fixed", "model.fixed.k_sigma", "model.fixed.b_tau", "model.hold",
    "model.options.shear_link", "model.options.n_arms", "model.options.layers",
    "solver.options.jacobian", "solver.options.xtol", "solver.options.strategy.spread",
    "solver.options.strategy.search_box", "solver.options.strategy.seed", "solver.options.strategy.time_scale",
    "solver.options.strategy.time_scale_range", "solver.options.strategy.confirm",
    "solver.options.strategy.stage_max_nfev", "solver.options.strategy.whiteness_threshold",
    "solver.options.strategy.coordinate_scan", "solver.options.strategy.bands", "solver.options.strategy.n_starts",
    "nuisance.input_gain.estimate", "nuisance.input_gain.value", "nuisance.delay.estimate", "nuisance.delay.value",
    "nuisance.max_delay", "identifiability.max_correlation", "identifiability.max_relative_se",
    "identifiability.precise_relative_se", "solver.options.strategy.min_excess",
    "compensator.options", "compensator.options.calibration", "output.plots", "title", "calibration",
    "calibration.lengths", "calibration.band", "calibration.output", "calibration.analysis", "design",
]


def nasty_value(c, current: Any = None) -> Any:
    kind = c.integer(0, 9)
    if kind <= 3:
        return c.choice(NASTY_NUMBERS)
    if kind <= 5:
        return c.choice(NASTY_STRINGS)
    if kind <= 7:
        return copy.deepcopy(c.choice(NASTY_OTHER))
    if isinstance(current, (int, float)) and not isinstance(current, bool):  # near the valid value
        return current * c.choice([-1, 0, 1e-12, 1e-3, 0.999, 1.001, 10, 1e3, 1e12])
    return c.choice(NASTY_NUMBERS)


# -- config mutation -------------------------------------------------------------------------------
def key_paths(data: Any, prefix: str = "") -> list[str]:
    out = []
    if isinstance(data, dict):
        for k, v in data.items():
            path = f"{prefix}.{k}" if prefix else str(k)
            out.append(path)
            out += key_paths(v, path)
    return out


def set_path(data: dict, path: str, value: Any) -> None:
    parts = path.split(".")
    node = data
    for p in parts[:-1]:
        child = node.get(p) if isinstance(node, dict) else None
        if not isinstance(child, dict):
            child = {}
            node[p] = child
        node = child
    node[parts[-1]] = value


def get_path(data: dict, path: str) -> Any:
    node: Any = data
    for p in path.split("."):
        if not isinstance(node, dict) or p not in node:
            return None
        node = node[p]
    return node


def delete_path(data: dict, path: str) -> None:
    parts = path.split(".")
    node = get_path(data, ".".join(parts[:-1])) if len(parts) > 1 else data
    if isinstance(node, dict):
        node.pop(parts[-1], None)


def typo(c, word: str) -> str:
    if not word:
        return "x"
    i = c.integer(0, len(word) - 1)
    return c.choice([word[:i] + word[i + 1:], word[:i] + word[i] * 2 + word[i + 1:], word.upper(), word + "s"])


def near_value(c, current: Any) -> Any:
    """A value of the same type as ``current`` that may still be valid: the deep paths get run."""
    if isinstance(current, bool):
        return not current
    if isinstance(current, int):
        return c.choice([current - 1, current + 1, 0, 1, 2 * current, current // 2, 10 * current, -current])
    if isinstance(current, float):
        return current * c.choice([1e-300, 1e-12, 1e-6, 1e-3, 0.1, 0.5, 0.999, 1.001, 2.0, 10.0, 1e3, 1e6, 1e12,
                                   1e300, -1.0, 0.0])
    if isinstance(current, str):
        return c.choice([current.upper(), current + "_", "", current[:-1]])
    if isinstance(current, list) and current:
        return c.choice([current[:-1], current + current[-1:], current[::-1]])
    return nasty_value(c, current)


def mutate_config_data(c, data: dict) -> list[str]:
    """Apply 1-3 structural mutations; returns their descriptions (key paths included)."""
    steps = []
    for _ in range(c.choice([1, 1, 1, 2, 2, 3])):
        paths = key_paths(data) + EXTRA_KEYS
        op = c.choice(["near"] * 7 + ["nasty"] * 5 + ["plugin"] * 3 + ["delete"] * 2 + ["rename", "rename", "section"])
        path = c.choice(paths)
        if op in ("near", "nasty"):
            current = get_path(data, path)
            value = near_value(c, current) if op == "near" and current is not None else nasty_value(c, current)
            set_path(data, path, value)
            steps.append(f"set {path}={str(value)[:40]!r}")
        elif op == "delete":
            delete_path(data, path)
            steps.append(f"delete {path}")
        elif op == "rename":
            value = get_path(data, path)
            delete_path(data, path)
            parts = path.split(".")
            new = ".".join(parts[:-1] + [typo(c, parts[-1])])
            set_path(data, new, value)
            steps.append(f"rename {path} -> {new}")
        elif op == "plugin":
            key = c.choice(list(PLUGIN_NAMES))
            set_path(data, key, c.choice(PLUGIN_NAMES[key]))
            steps.append(f"set {key}={get_path(data, key)}")
        else:
            section = c.choice(list(data) or ["sample"])
            data[section] = nasty_value(c)
            steps.append(f"replace section {section}")
    return steps


def alias_bomb(levels: int) -> str:
    lines = ['  b0: &b0 ["x", "x", "x", "x", "x", "x", "x", "x"]']
    for k in range(1, levels):
        lines.append(f"  b{k}: &b{k} [" + ", ".join([f"*b{k - 1}"] * 8) + "]")
    return "design:\n" + "\n".join(lines) + "\n"


def mutate_text(c, text: str) -> tuple[bytes, str]:
    """A text-level mutation of the YAML (syntax, encoding, bombs)."""
    op = c.choice(["truncate", "insert", "flip", "dup_line", "indent", "utf16", "latin1", "bom", "bomb", "deep",
                   "tab", "anchor", "tag", "merge", "duplicate_key", "empty", "binary"])
    raw = text.encode("utf-8")
    if op == "truncate":
        return raw[: c.integer(0, len(raw))], op
    if op == "insert":
        i = c.integer(0, len(raw))
        return raw[:i] + c.choice([b"\x00", b"\xff\xfe", b":", b"- ", b"{", b"]", b"'", b'"', b"&a ", b"*a", b"!!",
                                   b"\t", b"%YAML 1.1\n", b"---\n", b"\xe2\x80\xa8"]) + raw[i:], op
    if op == "flip":
        data = bytearray(raw)
        for _ in range(c.integer(1, 4)):
            i = c.integer(0, max(len(data) - 1, 0))
            if data:
                data[i] = c.integer(0, 255)
        return bytes(data), op
    lines = text.splitlines()
    if op == "dup_line" and lines:
        i = c.integer(0, len(lines) - 1)
        lines.insert(i, lines[i])
    elif op == "indent" and lines:
        i = c.integer(0, len(lines) - 1)
        lines[i] = " " * c.integer(1, 5) + lines[i]
    elif op == "utf16":
        return text.encode("utf-16"), op
    elif op == "latin1":
        return ("title: Stärke\n" + text).encode("latin-1", errors="replace"), op
    elif op == "bom":
        return b"\xef\xbb\xbf" + raw, op
    elif op == "bomb":
        return (text + alias_bomb(c.integer(3, 10))).encode(), op
    elif op == "deep":
        depth = c.choice([10, 63, 64, 65, 200, 1000, 5000])
        return (text + "design: " + "[" * depth + "]" * depth + "\n").encode(), op
    elif op == "tab" and lines:
        i = c.integer(0, len(lines) - 1)
        lines[i] = "\t" + lines[i]
    elif op == "anchor":
        return (text.replace("sample:", "sample: &s", 1) + "extra: *s\n").encode(), op
    elif op == "tag":
        tag = c.choice(["!!float abc", "!!int 1.5", "!!binary ###", "!!timestamp x", "!!set {a}", "!!python/name:os.getcwd ''",
                        "!!omap [a]", "!!str", "!custom 1", "!!float 1e400", "!!int 99999999999999999999999"])
        return (text + f"title: {tag}\n").encode(), op
    elif op == "merge":
        return (text + "x: &m {a: 1}\ny: {<<: *m, <<: [*m, *m]}\n").encode(), op
    elif op == "duplicate_key":
        return (text + "title: again\nsample: {length: 1}\n").encode(), op
    elif op == "empty":
        return c.choice([b"", b"\n", b"---\n", b"...\n", b"# nothing\n", b"null\n", b"[]\n", b"42\n"]), op
    elif op == "binary":
        return bytes(c.integer(0, 255) for _ in range(c.integer(1, 200))), op
    return ("\n".join(lines) + "\n").encode(), op


# -- cases ---------------------------------------------------------------------------------------------
@dataclass
class Case:
    """One invocation of mbus-run in ``folder`` (the case's own sandbox)."""

    folder: Path
    argv: list[Any]
    names: list[str]
    description: list[str]
    allowed: list[str] = field(default_factory=list)  # paths relative to folder that may be written
    config_text: str = ""  # the (mutated) config, for paths it names
    protected: dict[str, bytes] = field(default_factory=dict)  # relative path -> bytes that must stay


CALIBRATION_STATE = ["absent", "present", "present+overwrite"]


def config_case(c, folder: Path, materials: "Materials") -> Case:
    """A mutated config (structure and/or text), run against the simulated rig or a data file."""
    folder.mkdir(parents=True, exist_ok=True)
    base = c.choice(["small", "small", "small", "calibration", "file_csv", "from_file"])
    data = copy.deepcopy(rs.CALIBRATION if base == "calibration" else rs.SMALL)
    protected: dict[str, bytes] = {}
    allowed = ["out"]
    argv_extra: list[str] = []
    if base == "file_csv":
        data["backend"] = rs.file_backend(materials.copy_into(folder, "csv"))
    if base == "from_file":
        wave = materials.copy_into(folder, "waveform")
        data["excitation"] = {"name": "from_file", "options": {"path": str(wave), "file_sample_rate": 2.0e6}}
    if base == "calibration":
        state = c.choice(CALIBRATION_STATE)
        if state != "absent":
            for suffix in (".npz", ".json"):
                (folder / f"calibration{suffix}").write_bytes(b"an existing calibration " + suffix.encode())
                protected[f"calibration{suffix}"] = (folder / f"calibration{suffix}").read_bytes()
        if state == "present+overwrite":
            argv_extra.append("--overwrite")
            protected = {}
        allowed += ["calibration.npz", "calibration.json"]
    description = [f"base {base}"]
    description += mutate_config_data(c, data)
    text = yaml.safe_dump(_yaml_safe(data), sort_keys=False, allow_unicode=True)
    if c.chance(0.15):
        raw, op = mutate_text(c, text)
        description.append(f"text {op}")
    else:
        raw = text.encode("utf-8")
    config_path = folder / "run.yaml"
    config_path.write_bytes(raw)
    overrides = []
    if c.chance(0.2):  # the same mutation as a --set override
        key = c.choice(key_paths(data) + EXTRA_KEYS)
        value = c.choice(["1e400", ".nan", "-1", "0", "[1, 2", "{a: 1}", "!!float x", "", "x" * 5000, "1e-400",
                          "[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]",
                          "~", "'quoted'", "a: b: c"])
        overrides = ["--set", f"{key}={value}"]
        description.append(f"--set {key}={value[:30]!r}")
    out: Path = folder / "out"
    if c.chance(0.05):  # an output folder that must not be used or replaced
        what = c.choice(["file", "under_file", "run", "other"])
        if what in ("file", "under_file"):
            (folder / "notes.txt").write_text("keep")
            protected["notes.txt"] = b"keep"
            out = folder / "notes.txt" if what == "file" else folder / "notes.txt" / "run"
        else:
            out.mkdir()
            name = "status.json" if what == "run" else "thesis.tex"
            (out / name).write_text('{"status": "done"}')
            if what == "other" or "--overwrite" not in argv_extra:  # --overwrite may replace a run, only a run
                protected[f"out/{name}"] = b'{"status": "done"}'
        description.append(f"-o {what}")
    argv: list[Any] = [config_path, "-o", out, "--no-plots", "-q", *argv_extra, *overrides]
    names = [str(config_path), str(folder), "--set", *_flat_names(data)]
    allowed += _calibration_outputs(_effective(data, overrides[1:]), folder)  # any config may become one
    return Case(folder, argv, names, description, allowed=allowed, protected=protected,
                config_text=raw.decode("utf-8", "replace"))


def _effective(data: dict, overrides: list[str]) -> dict:
    """``data`` with the case's --set overrides applied as mbus-run applies them."""
    from mbus_framework.errors import MbusError
    from mbus_framework.pipeline.config import apply_overrides

    try:
        return apply_overrides(data, overrides)
    except MbusError:
        return data


def _calibration_outputs(data: dict, folder: Path) -> list[str]:
    """Relative paths a (mutated) calibration.output may name: it is a path the config names."""
    out = get_path(data, "calibration.output")
    if not isinstance(out, str) or not out or os.path.isabs(out):
        return []
    p = Path(out)
    names = [str(p), str(p.with_suffix(".npz")) if p.name else str(p), str(p.with_suffix(".json")) if p.name else str(p)]
    return [n for n in names if not n.startswith("..")]


def _flat_names(data: dict) -> list[str]:
    return [p.split(".")[-1] for p in key_paths(data)]


def _yaml_safe(obj: Any) -> Any:
    """Make values yaml.safe_dump can write (dates stay dates; everything else plain)."""
    if isinstance(obj, dict):
        return {(k if isinstance(k, (str, int, float, bool)) or k is None else str(k)): _yaml_safe(v)
                for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_yaml_safe(v) for v in obj]
    return obj


# -- data files ------------------------------------------------------------------------------------
DATA_FORMATS = ["csv", "npz", "gds_raw", "gds_detail", "lab_run", "run_folder"]


class Materials:
    """The unmutated data files of every format, made once and copied into each case."""

    def __init__(self, root: Path) -> None:
        self.root = root
        root.mkdir(parents=True, exist_ok=True)
        self.csv = rs.write_tuy_csv(root)
        self.npz = rs.write_tuy_npz(root)
        (root / "raw").mkdir(exist_ok=True)
        (root / "detail").mkdir(exist_ok=True)
        self.gds_raw = rs.write_gds_pair(root / "raw", "raw")
        self.gds_detail = rs.write_gds_pair(root / "detail", "detail")
        self.lab_run = rs.write_lab_run(root / "lab", shots=2)
        wave = root / "waveform.csv"
        wave.write_text("u\n" + "\n".join(f"{v:g}" for v in rs.designed().u[::5]) + "\n")
        self.waveform = wave
        run = root / "run_folder"
        code = rs.run_cli([rs.write_yaml(root / "sim.yaml", rs.config()), "-o", run, "-q"]).code
        assert code == 0
        self.run_folder = run

    def copy_into(self, folder: Path, fmt: str) -> Path:
        """Copy the material of ``fmt`` into ``folder``; returns the path the backend reads."""
        if fmt in ("csv", "npz", "waveform"):
            src = getattr(self, fmt)
            return Path(shutil.copy(src, folder / src.name))
        if fmt.startswith("gds"):
            ch1, ch2 = getattr(self, fmt)
            shutil.copy(ch1, folder / ch1.name)
            shutil.copy(ch2, folder / ch2.name)
            return folder / ch1.name
        src = getattr(self, fmt)
        dest = folder / fmt
        shutil.copytree(src, dest)
        return dest


NASTY_TOKENS = ["nan", "inf", "-inf", "NaN", "1e308", "-1e308", "1e400", "-1e400", "1e-400", "", " ", "abc", "1,2",
                "0x10", "١٢٣", "∞", "1e", "--1", "1.2.3", "0" * 400, "9" * 400, "\x00", "é"]


def mutate_lines(c, path: Path, keep_header: bool = False) -> str:
    text = path.read_bytes().decode("latin-1")
    lines = text.splitlines()
    op = c.choice(["drop", "dup", "swap", "token", "token", "header", "sep", "crlf", "long", "utf16", "bom", "empty"])
    first = 1 if keep_header and len(lines) > 1 else 0
    if op == "drop" and lines:
        del lines[c.integer(first, len(lines) - 1)]
    elif op == "dup" and lines:
        i = c.integer(0, len(lines) - 1)
        lines[i:i] = [lines[i]] * c.integer(1, 3)
    elif op == "swap" and len(lines) > 2:
        i, j = c.integer(0, len(lines) - 1), c.integer(0, len(lines) - 1)
        lines[i], lines[j] = lines[j], lines[i]
    elif op == "token" and lines:
        i = c.integer(0, len(lines) - 1)
        fields = lines[i].split(",")
        fields[c.integer(0, len(fields) - 1)] = c.choice(NASTY_TOKENS)
        lines[i] = ",".join(fields)
    elif op == "header" and lines:
        lines[0] = c.choice(["t,u", "u,y,t", "t,u,y,z", "T,U,Y", "time,u,y", "t;u;y", "", "t,u,y,y", "t\tu\ty"])
    elif op == "sep":
        lines = [ln.replace(",", c.choice([";", "\t", " ", ", "])) for ln in lines]
    elif op == "crlf":
        path.write_bytes(("\r\n".join(lines) + "\r\n").encode("latin-1"))
        return op
    elif op == "long" and lines:
        lines.insert(c.integer(0, len(lines)), "1," * c.integer(1, 50_000))
    elif op == "utf16":
        path.write_bytes(("\n".join(lines) + "\n").encode("utf-16"))
        return op
    elif op == "bom":
        path.write_bytes(b"\xef\xbb\xbf" + ("\n".join(lines) + "\n").encode("latin-1"))
        return op
    elif op == "empty":
        lines = []
    path.write_bytes(("\n".join(lines) + ("\n" if lines else "")).encode("latin-1", errors="replace"))
    return op


def mutate_bytes(c, path: Path) -> str:
    raw = bytearray(path.read_bytes())
    op = c.choice(["flip", "insert", "delete", "truncate", "append"])
    if op == "flip" and raw:
        for _ in range(c.integer(1, 8)):
            raw[c.integer(0, len(raw) - 1)] = c.integer(0, 255)
    elif op == "insert":
        i = c.integer(0, len(raw))
        raw[i:i] = bytes(c.integer(0, 255) for _ in range(c.integer(1, 16)))
    elif op == "delete" and raw:
        i = c.integer(0, len(raw) - 1)
        del raw[i:i + c.integer(1, 64)]
    elif op == "truncate":
        del raw[c.integer(0, len(raw)):]
    else:
        raw += bytes(c.integer(0, 255) for _ in range(c.integer(1, 64)))
    path.write_bytes(bytes(raw))
    return op


def mutate_npz(c, path: Path) -> str:
    try:
        with np.load(path, allow_pickle=True) as z:  # our own file, mutated before: pickles allowed here
            arrays = dict(z)
    except Exception:  # noqa: BLE001 - already corrupted by a byte mutation
        return mutate_bytes(c, path)
    if not arrays:
        return "empty"
    name = c.choice(sorted(arrays))
    a = arrays[name]
    op = c.choice(["drop", "rename", "dtype", "shape", "value", "value", "length", "extra", "scalar", "object"])
    if op == "drop":
        del arrays[name]
    elif op == "rename":
        arrays[typo(c, name)] = arrays.pop(name)
    elif op == "dtype":
        dtype = c.choice([np.int8, np.int64, bool, np.complex128, np.float16, "U3", "S2"])
        try:
            with np.errstate(all="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore")  # ComplexWarning: the mutation means it
                arrays[name] = a.astype(dtype)
        except (ValueError, TypeError):  # a string array that is not a number
            arrays[name] = np.full(a.shape, 7, dtype=dtype)
    elif op == "shape":
        flat = np.atleast_1d(a)
        arrays[name] = c.choice([flat.reshape(1, -1), flat[:0], flat[:1], np.stack([flat, flat]), flat.reshape(-1)[::2]])
    elif op == "value" and a.size and a.dtype.kind in "fiu":
        b = a.astype(float).copy().ravel()
        b[c.integer(0, b.size - 1)] = c.choice([np.nan, np.inf, -np.inf, 1e308, -1e308, 0.0, 1e-320, 2.0**70])
        arrays[name] = b.reshape(a.shape)
    elif op == "length" and a.ndim == 1 and a.size > 2:
        arrays[name] = a[: c.integer(0, a.size - 1)]
    elif op == "extra":
        arrays[typo(c, name)] = np.zeros(c.integer(0, 5))
    elif op == "scalar":
        arrays[name] = np.float64(c.choice([0.0, -1.0, np.nan, 1e300, 3.0]))
    elif op == "object":
        np.savez(path, **{k: v for k, v in arrays.items() if k != name}, **{name: np.array([None, 1], dtype=object)})
        return f"{op} {name}"
    np.savez(path, **arrays)
    return f"{op} {name}"


def mutate_json(c, path: Path) -> str:
    try:
        doc = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError):
        return mutate_bytes(c, path)
    op = c.choice(["value", "value", "delete", "top", "nested"])
    if op == "top":
        doc = c.choice([[doc], "text", 42, None, []])
    elif isinstance(doc, dict) and doc:
        key = c.choice(sorted(doc))
        if op == "delete":
            del doc[key]
        elif op == "nested" and isinstance(doc[key], dict) and doc[key]:
            inner = c.choice(sorted(doc[key]))
            doc[key][inner] = _json_value(c)
        else:
            doc[key] = c.choice([_json_value(c), "running", "acquiring", "complete", "failed"])
    path.write_text(json.dumps(doc, allow_nan=True))
    return f"json {op}"


def _json_value(c) -> Any:
    v = nasty_value(c)
    return str(v) if isinstance(v, _dt.date) else v


def mutate_gds_header(c, path: Path) -> str:
    lines = path.read_bytes().decode("latin-1").splitlines()
    keys = ["Memory Length", "Sampling Period", "Vertical Scale", "Mode", "Source", "Vertical Units", "Firmwave"]
    key = c.choice(keys)
    value = c.choice(["1e400", "inf", "nan", "0", "-1", "", "abc", "1e-300", "2.5uS", "500mV", "Detail", "Fast",
                      "99999999999999999999", "400", "1e9", "5e-7"])
    idx = next((i for i, ln in enumerate(lines) if ln.startswith(key + ",")), None)
    if idx is None or c.chance(0.2):
        lines.insert(0, f"{key},{value},")
    elif c.chance(0.2):
        del lines[idx]
        value = "(deleted)"
    else:
        lines[idx] = f"{key},{value},"
    path.write_bytes(("\r\n".join(lines) + "\r\n").encode("latin-1", errors="replace"))
    return f"header {key}={value}"


def special_file(c, path: Path) -> str:
    """Replace ``path`` by something that is not a regular file."""
    if path.is_dir():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)
    kind = c.choice(["fifo", "dir", "loop", "zero", "missing", "dangling"])
    if kind == "fifo" and hasattr(os, "mkfifo"):
        os.mkfifo(path)
    elif kind == "dir":
        path.mkdir()
    elif kind == "loop":
        path.symlink_to(path)
    elif kind == "zero" and os.path.exists("/dev/zero"):
        path.symlink_to("/dev/zero")
    elif kind == "dangling":
        path.symlink_to(path.parent / "nowhere")
    return f"special {kind}"


def data_case(c, folder: Path, materials: Materials, fmt: str | None = None) -> Case:
    """A mutated data file of one format, fitted through the ``file`` backend."""
    folder.mkdir(parents=True, exist_ok=True)
    fmt = fmt or c.choice(DATA_FORMATS)
    target = materials.copy_into(folder, fmt)
    description = [f"format {fmt}"]
    options: dict[str, Any] = {}
    files: list[Path] = []
    if fmt.startswith("gds"):
        options["response_path"] = str(folder / materials.gds_raw[1].name)
        files = [target, folder / materials.gds_raw[1].name]
    elif fmt == "lab_run":
        files = sorted((target / "shots").iterdir()) + [target / "status.json"]
    elif fmt == "run_folder":
        files = [target / "measurement.csv", target / "measurement.json", target / "status.json"]
    else:
        files = [target]
    for _ in range(c.integer(1, 2)):
        f = c.choice(files)
        if c.chance(0.05):
            description.append(f"{f.name}: {special_file(c, f)}")
            continue
        if not f.is_file() or f.is_symlink():
            continue
        if f.suffix.lower() == ".npz":
            op = mutate_npz(c, f) if c.chance(0.75) else mutate_bytes(c, f)
        elif f.suffix.lower() == ".json":
            op = mutate_json(c, f)
        elif f.suffix.lower() == ".csv":
            if fmt.startswith("gds") and c.chance(0.4):
                op = mutate_gds_header(c, f)
            else:
                op = mutate_lines(c, f) if c.chance(0.8) else mutate_bytes(c, f)
        else:
            op = mutate_bytes(c, f)
        description.append(f"{f.name}: {op}")
    if c.chance(0.1):
        options["format"] = c.choice(["tuy", "gds_csv", "lab_run", "run", "auto"])
        description.append(f"format option {options['format']}")
    if c.chance(0.1) and fmt in ("lab_run", "gds_raw", "gds_detail"):
        options["processing"] = c.choice([{"u_gain": 0.0}, {"y_gain": 1e300}, {"align": {"enabled": False}},
                                          {"input": "designed"}, {"align": {"window": "record"}},
                                          {"align": {"min_correlation": 0.0}}])
        description.append(f"processing {options['processing']}")
    cfg = rs.config(backend=rs.file_backend(target, **options))
    config_path = rs.write_yaml(folder / "run.yaml", cfg)
    names = [str(folder), str(config_path), "backend.options"]
    return Case(folder, [config_path, "-o", folder / "out", "--no-plots", "-q"], names, description,
                allowed=["out", *_written_by_recovery(fmt)])


def _written_by_recovery(fmt: str) -> list[str]:
    """Reading an abandoned run folder marks it interrupted: the data folder it names."""
    return [fmt] if fmt in ("lab_run", "run_folder") else []


# -- running a case ------------------------------------------------------------------------------------
@dataclass
class CaseResult:
    code: int
    seconds: float
    error: str
    json_files: int


def run_case(case: Case, timeout: float = 60.0) -> CaseResult:
    """Run ``case`` in its folder (the working directory) and check every invariant."""
    cwd = os.getcwd()
    os.chdir(case.folder)
    try:
        before = rs.tree(case.folder)
        outcome = rs.run_cli(case.argv, timeout=timeout)
        after = rs.tree(case.folder)
    finally:
        os.chdir(cwd)
    context = f"case: {'; '.join(case.description)}"
    try:
        rs.assert_clean_outcome(outcome, case.names, case.config_text)
        rs.check_writes(before, after, case.allowed)
        written = [case.folder / rel for rel in rs.changed(before, after) if rel.endswith(".json")]
        for path in written:
            if path.is_file() and not path.is_symlink():
                rs.strict_json(path)
        count = len(written)
        for rel, content in case.protected.items():
            assert (case.folder / rel).read_bytes() == content, f"{rel} was replaced without --overwrite"
    except AssertionError as exc:
        raise AssertionError(f"{context}\n{exc}") from None
    error = rs.error_lines(outcome.err)[0] if outcome.code else ""
    return CaseResult(outcome.code, outcome.seconds, error, count)


Builder = Callable[[Any, Path, Materials], Case]
