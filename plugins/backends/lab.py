"""``lab`` backend: SRS DS340 generator + GW Instek GDS-2062 scope (the dissertation's rig).

Sequence: open and configure the scope (channels, timebase, trigger) and the generator
(``*IDN?`` checks, arbitrary-waveform upload of the designed excitation scaled to +-2047, FSMP,
amplitude in Vpp, offset, single-shot burst); then for each of ``shots`` shots: arm the scope,
fire the generator (``*TRG``), wait, read the excitation and response channels and write the
shot to ``<run_dir>/shots/shot_NNNN.npz`` at once (atomically), with the instrument identities
and settings in ``shots/acquisition.json``. Finally every shot's excitation channel is aligned
with what the generator played, the shots are cut at the burst start, averaged and scaled
(``processing``), giving the ``t, u, y`` the run fits.

A timeout, a disconnect, a garbage reply or a rejected command stops the run with a one-line
``InstrumentError`` ("<instrument>: <step>: ..."); the shots saved so far stay on disk and
``acquisition.json`` records the error, so the ``file`` backend can re-fit from the folder
(``backend: {name: file, options: {path: <run_dir>}}``); Ctrl-C and SIGTERM record
``interrupted``, and a run killed outright is marked ``interrupted`` by the next run
(:mod:`mbus_framework.pipeline.run_folder`). Without a run directory in the context
(programmatic use) the shots go to a new temporary folder, named in the measurement's meta.
"""
from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from mbus_framework.interfaces.backend import AcquisitionContext, Backend, Measurement
from mbus_framework.errors import InstrumentError, MbusError
from mbus_framework.interfaces.hookspecs import BackendSpec, hookimpl
from mbus_framework.pipeline import interrupts
from mbus_plugins.instruments.ds340 import DS340, DS340Options, scale_to_points
from mbus_plugins.instruments.gds2000 import GDS2000, GDS2000Options
from mbus_plugins.instruments.shots import (
    SHOT_DIR,
    ProcessingOptions,
    Reference,
    Shot,
    combine,
    now,
    save_excitation,
    save_shot,
    write_acquisition,
)


class LabOptions(BaseModel):
    """``backend.options`` of the ``lab`` backend."""

    model_config = ConfigDict(extra="forbid")
    generator: DS340Options = Field(description="SRS DS340 connection and output settings")
    scope: GDS2000Options = Field(description="GW Instek GDS-2062 connection, channels, timebase, trigger")
    shots: int = Field(4, ge=1, le=10000, description="shots to acquire and average")
    processing: ProcessingOptions = Field(default_factory=ProcessingOptions,
                                          description="alignment, averaging and gains")


class LabBackend(Backend):
    """Acquire with the DS340 + GDS-2062 rig."""

    Options = LabOptions
    summary = "SRS DS340 generator + GW Instek GDS-2062 scope (RS-232 / USB serial)"

    def make_generator(self) -> DS340:
        return DS340(self.options.generator)

    def make_scope(self) -> GDS2000:
        return GDS2000(self.options.scope)

    def acquire(self, context: AcquisitionContext) -> Measurement:
        o = self.options
        run_dir = Path(context.run_dir) if context.run_dir else Path(tempfile.mkdtemp(prefix="mbus-lab-"))
        shot_dir = run_dir / SHOT_DIR
        wave = context.excitation
        k = o.generator.upload_decimation
        try:
            points = scale_to_points(wave.u[::k])
        except ValueError as exc:
            raise InstrumentError(f"{DS340.name}: upload: {exc}") from None
        requested_rate = o.generator.sample_rate or wave.sample_rate / k
        record: dict[str, Any] = {
            "status": "connecting", "started": now(), "error": None,
            "shots_requested": o.shots, "shots_saved": 0,
            "processing": o.processing.model_dump(mode="json"),
            "excitation": {"file": "excitation.npz", "n_samples": int(wave.u.size),
                           "sample_rate_hz": wave.sample_rate, "upload_decimation": k,
                           "points": int(points.size), "info": dict(wave.info)},
            "instruments": {},
        }
        write_acquisition(shot_dir, record)
        scope, generator = self.make_scope(), self.make_generator()
        shots: list[Shot] = []
        try:
            scope.open()
            scope.identify()
            scope.configure()
            generator.open()
            generator.identify()
            generator.upload(points)
            generator.configure(requested_rate)
            record["instruments"] = {
                "generator": {"identity": generator.identity, "settings": generator.settings},
                "scope": {"identity": scope.identity, "settings": scope.settings},
            }
            save_excitation(shot_dir, wave.t, wave.u, points, generator.settings["sample_rate_hz"],
                            o.generator.burst_count)
            record["status"] = "acquiring"
            write_acquisition(shot_dir, record)
            ex, resp = o.scope.excitation_channel, o.scope.response_channel
            for index in range(1, o.shots + 1):
                interrupts.check()  # a Ctrl-C swallowed inside a driver call stops here
                scope.arm()
                generator.trigger()
                scope.wait_acquired()
                tu = scope.read_trace(ex)
                ty = scope.read_trace(resp)
                if abs(tu.dt - ty.dt) > 1e-9 * tu.dt or tu.raw.size != ty.raw.size:
                    raise InstrumentError(f"{scope.name}: read CH{resp}: channels differ (dt {tu.dt:g}/{ty.dt:g} s, "
                                          f"{tu.raw.size}/{ty.raw.size} points)")
                shot = Shot(tu.dt, tu.volts, ty.volts, tu.raw, ty.raw, {
                    "index": index, "time": now(), "u_channel": ex, "y_channel": resp,
                    "u_volts_per_div": tu.volts_per_div, "y_volts_per_div": ty.volts_per_div,
                    "counts_per_division": o.scope.counts_per_division, "u_block": tu.info, "y_block": ty.info})
                save_shot(shot_dir, index, shot)
                shots.append(shot)
                record["shots_saved"] = index
                write_acquisition(shot_dir, record)
            record["status"] = "complete"
        except BaseException as exc:
            with interrupts.deferred():  # a second Ctrl-C or SIGTERM waits until the record is written
                record["status"] = "failed" if isinstance(exc, MbusError) else "interrupted"
                record["error"] = str(exc) or type(exc).__name__
                write_acquisition(shot_dir, record)
            raise
        finally:
            generator.close()
            scope.close()
        write_acquisition(shot_dir, record)
        reference = Reference(points.astype(float), generator.settings["sample_rate_hz"], o.generator.burst_count)
        t, u, y, meta = combine(shots, reference, o.processing, str(shot_dir))
        meta.update(source="lab", shot_dir=str(shot_dir), warnings=_warnings(shots, generator.settings),
                    instruments=record["instruments"])
        return Measurement(t, u, y, meta=meta)


def _warnings(shots: list[Shot], generator_settings: dict[str, Any]) -> list[str]:
    """Things the user should look at (clipping, rounded sample rate, 8-bit-looking data)."""
    out = []
    asked, got = generator_settings.get("sample_rate_requested_hz"), generator_settings.get("sample_rate_hz")
    if asked and got and abs(asked - got) > 1e-6 * asked:
        out.append(f"DS340 sample rate is {got:g} Hz, {asked:g} Hz was requested")
    for s in shots:
        for name in ("u", "y"):
            info = s.meta.get(f"{name}_block", {})
            if info.get("clipped"):
                out.append(f"shot {s.meta['index']}: channel {s.meta[f'{name}_channel']} reaches the screen edge "
                           f"(increase V/div)")
            if info.get("low_bytes_all_zero"):
                out.append(f"shot {s.meta['index']}: channel {s.meta[f'{name}_channel']} has only multiples of 256 "
                           f"(8-bit data in the high byte? check counts_per_division)")
    return out


@hookimpl
def mbus_backends():
    return [BackendSpec("lab", LabBackend, LabBackend.summary)]
