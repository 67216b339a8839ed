"""The saved crispness model: a JSON file of weights and scalings (no pickled code).

Format ``mbus-crispness-model``, version 1 (docs/crispness.md):

    {
      "format": "mbus-crispness-model", "version": 1,
      "inputs": ["k_sigma", "k_tau", ...],               # table columns, in network order
      "input_scaling": {"low": [...], "high": [...]},     # z = (x - low) / (high - low)
      "output_scaling": {"low": s_lo, "high": s_hi},      # score = s_lo + y (s_hi - s_lo)
      "network": {"hidden_layer_sizes": [6], "activation": "tanh", "output": "linear"},
      "members": [{"layers": [{"W": [[...]], "b": [...]}, ...]}, ...],   # averaged
      "training": {...}                                   # provenance (free-form)
    }

Each member's layers go from the first hidden layer to the output; W has one row per
neuron of the layer and one column per neuron (or input) of the layer before. The
prediction for a table row is the mean of the members' outputs; inputs outside the training
range [low, high] are flagged as extrapolation.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pandas as pd
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from mbus_framework.analysis.crispness.network import MLP, MinMaxScaling
from mbus_framework.analysis.crispness.regressor import LMNetworkRegressor
from mbus_framework.analysis.table import require_columns
from mbus_framework.errors import DataError
from mbus_framework.pipeline.storage import atomic_write_text, to_jsonable

FORMAT = "mbus-crispness-model"
VERSION = 1


class _Layer(BaseModel):
    model_config = ConfigDict(extra="forbid")
    W: list[list[float]]
    b: list[float]


class _Member(BaseModel):
    model_config = ConfigDict(extra="forbid")
    layers: list[_Layer]


class _Scaling(BaseModel):
    model_config = ConfigDict(extra="forbid")
    low: list[float]
    high: list[float]


class _OutputScaling(BaseModel):
    model_config = ConfigDict(extra="forbid")
    low: float
    high: float


class _Network(BaseModel):
    model_config = ConfigDict(extra="forbid")
    hidden_layer_sizes: list[int] = Field(min_length=1)
    activation: Literal["tanh", "logistic"]
    output: Literal["linear"] = "linear"


class ModelFile(BaseModel):
    model_config = ConfigDict(extra="forbid")
    format: Literal["mbus-crispness-model"]
    version: Literal[1]
    inputs: list[str] = Field(min_length=1)
    input_scaling: _Scaling
    output_scaling: _OutputScaling
    network: _Network
    members: list[_Member] = Field(min_length=1)
    training: dict[str, Any] = Field(default_factory=dict)


class CrispnessModel:
    """A fitted network together with the table columns it reads."""

    def __init__(self, inputs: list[str], regressor: LMNetworkRegressor, training: dict[str, Any] | None = None):
        if len(inputs) != regressor.n_features_in_:
            raise ValueError(f"{len(inputs)} input names for a network of {regressor.n_features_in_} inputs")
        self.inputs = list(inputs)
        self.regressor = regressor
        self.training = dict(training or {})

    # -- file I/O ----------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        r = self.regressor
        members = [{"layers": [{"W": W.tolist(), "b": b.tolist()} for W, b in r.net_.layers(w)]} for w in r.members_]
        return {
            "format": FORMAT, "version": VERSION, "inputs": self.inputs,
            "input_scaling": {"low": np.asarray(r.x_scaling_.low).tolist(), "high": np.asarray(r.x_scaling_.high).tolist()},
            "output_scaling": {"low": float(np.ravel(r.y_scaling_.low)[0]), "high": float(np.ravel(r.y_scaling_.high)[0])},
            "network": {"hidden_layer_sizes": list(r.net_.hidden), "activation": r.net_.activation, "output": "linear"},
            "members": members, "training": json_safe(self.training),
        }

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        atomic_write_text(path, json.dumps(self.to_dict(), indent=1, allow_nan=False) + "\n")
        return path

    @classmethod
    def load(cls, path: str | Path) -> "CrispnessModel":
        p = Path(path)
        if not p.is_file():
            raise DataError(f"{p}: model file not found")
        try:
            data = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise DataError(f"{p}: not a JSON model file ({str(exc).splitlines()[0][:160]})") from None
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise DataError(f"{p}: not an {FORMAT} file (format key is {data.get('format') if isinstance(data, dict) else None!r})")
        try:
            spec = ModelFile.model_validate(data)
        except ValidationError as exc:
            err = exc.errors()[0]
            where = ".".join(str(x) for x in err["loc"])
            raise DataError(f"{p}: {where}: {err['msg']}") from None
        return cls.from_spec(spec, str(p))

    @classmethod
    def from_spec(cls, spec: ModelFile, source: str) -> "CrispnessModel":
        d = len(spec.inputs)
        if len(spec.input_scaling.low) != d or len(spec.input_scaling.high) != d:
            raise DataError(f"{source}: input_scaling needs {d} low and high values (one per input)")
        net = MLP(d, spec.network.hidden_layer_sizes, spec.network.activation)
        weights = []
        for k, m in enumerate(spec.members):
            try:
                weights.append(net.pack([(np.array(L.W, dtype=float), np.array(L.b, dtype=float)) for L in m.layers]))
            except ValueError:
                shapes = " ".join(f"{o}x{i}" for o, i in net.shapes)
                raise DataError(f"{source}: members.{k}.layers do not fit a {net!r} (W shapes {shapes})") from None
        xs = MinMaxScaling(np.array(spec.input_scaling.low), np.array(spec.input_scaling.high))
        ys = MinMaxScaling(np.array([spec.output_scaling.low]), np.array([spec.output_scaling.high]))
        return cls(spec.inputs, LMNetworkRegressor.from_members(net, weights, xs, ys), spec.training)

    # -- scoring -----------------------------------------------------------------------------
    def predict_table(self, table: pd.DataFrame, source: str = "<table>") -> pd.DataFrame:
        """Predicted score per table row: sample_id, predicted, member_sd, extrapolated inputs."""
        require_columns(table, ["sample_id", *self.inputs], source)
        X = table[self.inputs].apply(pd.to_numeric, errors="coerce")
        bad = X.isna().any(axis=1)
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            col = X.columns[X.iloc[row].isna()][0]
            raise DataError(f"{source}: row {row + 2} (sample {table['sample_id'].iloc[row]!r}), column {col}: missing or not a number")
        values = X.to_numpy(dtype=float)
        members = self.regressor.predict_members(values)
        low, high = self.regressor.x_scaling_.low, self.regressor.x_scaling_.high
        outside = [
            ",".join(name for name, v, lo, hi in zip(self.inputs, row, low, high) if not lo <= v <= hi) for row in values
        ]
        out = pd.DataFrame({"sample_id": table["sample_id"].astype(str).to_numpy(), "predicted": members.mean(axis=0)})
        out["member_sd"] = members.std(axis=0, ddof=1) if len(members) > 1 else 0.0
        out["extrapolated"] = outside
        return out


def json_safe(x):
    """JSON-safe copy: numpy to Python (pipeline.storage.to_jsonable), NaN and inf to None."""

    def finite(v):
        if isinstance(v, dict):
            return {k: finite(u) for k, u in v.items()}
        if isinstance(v, list):
            return [finite(u) for u in v]
        return None if isinstance(v, float) and not np.isfinite(v) else v

    return finite(to_jsonable(x))
