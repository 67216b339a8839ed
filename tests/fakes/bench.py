"""The rig without hardware: DS340 output -> simulated medium -> GDS-2000 channels."""
from __future__ import annotations

import numpy as np

from mbus_framework.engine.simulation import simulate

from .ds340 import FakeDS340
from .gds2000 import FakeGDS2000


class Bench:
    """When the fake generator fires, put its burst on the excitation channel and the simulated
    medium's response on the response channel of the fake scope.

    The burst starts ``pretrigger`` x record length into the record plus 0..``jitter`` samples
    (a different draw each shot); ``noise`` adds Gaussian noise with that fraction of each
    channel's RMS. The response is ``simulate(model, theta, u - idle, dt) * y_gain`` on the
    scope's sample grid (ZOH), so the fitted model can represent it exactly.
    """

    def __init__(self, generator: FakeDS340, scope: FakeGDS2000, model, theta, *, pretrigger: float = 0.1,
                 jitter: int = 3, noise: float = 0.0, seed: int = 0, y_gain: float = 1.0,
                 excitation_channel: int = 1, response_channel: int = 2):
        self.generator, self.scope = generator, scope
        self.model, self.theta = model, np.asarray(theta, float)
        self.pretrigger, self.jitter, self.noise, self.y_gain = pretrigger, jitter, noise, y_gain
        self.channels = (excitation_channel, response_channel)
        self.rng = np.random.default_rng(seed)
        self.starts: list[int] = []
        generator.on_trigger = self.fire

    def fire(self, generator: FakeDS340) -> None:
        values, rate, idle = generator.output()
        scope = self.scope
        n, dt = scope.record_points, scope.dt
        start = int(self.pretrigger * n) + int(self.rng.integers(0, self.jitter + 1))
        k = np.arange(n) - start
        index = np.floor(k * dt * rate + 1e-9).astype(np.int64)
        playing = (k >= 0) & (index < values.size)
        u = np.full(n, idle)
        u[playing] = values[index[playing]]
        y = simulate(self.model, self.theta, u - idle, dt) * self.y_gain
        if self.noise:
            u = u + self.noise * np.sqrt(np.mean(u**2)) * self.rng.standard_normal(n)
            y = y + self.noise * np.sqrt(np.mean(y**2)) * self.rng.standard_normal(n)
        if scope.capture({self.channels[0]: u, self.channels[1]: y}, dt):
            self.starts.append(start)
